"""Why the midpoint rod blows up on stiff nonlinear motion: the measurements of docs/theory.md §12.

Run:  python scripts/rod_stiff_diagnosis.py [--quick]      (about 6-9 min on one core; --quick: tables A, C, E only)

Cases: PyElastica's benchmark section (solid, radius 1 cm, E = 1 MPa, rho = 1000, G = E/1.5, shear
coefficient 4/3, L = 1 m), free, released from a uniform arc (body curvature kappa about z) while
spinning at Omega about z; N = 50 elements.  Prints
  A  the energy error against the step (instability bands),
  B  the threshold step h* for several sections, resolutions, spins and curvatures, with h* omega_max,
  C  which ingredients are needed (linear amplitude, spin only, big rigid rotations per step, 2D vs 3D),
  D  which linear modes gain the energy (modal kinetic energy by frequency band),
  E  a standalone planar rod in exact-angle coordinates: Cayley vs angle, strain midpoint vs the
     implicit midpoint rule vs an energy-conserving discrete gradient.
"""

import math
import sys
import time

import numpy as np
import scipy.linalg as sla

from varint import Simulation, build_model, parse_scene
from varint.errors import SolverError
from varint.terms.rod import unpack_level
from varint.analysis.rod_modes import rod_modes
from varint.scene.text import to_toml

N = 50
H_BAND = 5e-3  # inside the worst band of the base case


# ---------------------------------------------------------------------------------------------- scenes


def section(radius=0.01, E=1e6, rho=1000.0, inertia_factor=1.0, shear_factor=1.0, kshear=4 / 3):
    """Stiffness form of a solid circular section; rotary inertia and shear+stretch stiffness scalable."""
    G = E / 1.5
    A, I = math.pi * radius ** 2, math.pi * radius ** 4 / 4
    return dict(mass_per_length=rho * A, rotary_inertia=inertia_factor * rho * I, bending_stiffness=E * I,
                torsional_stiffness=G * 2 * I, axial_stiffness=shear_factor * E * A,
                shear_stiffness=shear_factor * kshear * G * A)


def make(n=N, h=H_BAND, sec=None, curvature=(0, 0, 2.0), spin=(0, 0, 2.0), dim=2, constraint="none"):
    rod = dict(sec or section(), dimension=dim, ends={"s0": "free", "sL": "free"}, constraint=constraint)
    ini = {}
    if any(curvature):
        ini["curvature"] = [float(c) for c in curvature]
    if any(spin):
        ini["angular_velocity"] = [float(c) for c in spin]
    d = {"tube": {"length": 1.0, "nodes": n + 1, "radius": 0.01}, "rod": rod, "time": {"step": h, "end": 1.0}}
    if ini:
        rod["initial"] = ini
    d["title"] = "stiff diagnosis"
    return build_model(parse_scene(to_toml(d)))


def run(model, h, steps, stop=10.0, on_step=None):
    """Energy history of a varint run; stops at a solver error or when |E/E0 - 1| > stop."""
    sim = Simulation(model, h=h)
    E = [sim.monitors()["energy"]]
    err = None
    for n in range(steps):
        try:
            sim.step()
        except SolverError as exc:
            err = str(exc).split(";")[0]
            break
        E.append(sim.monitors()["energy"])
        if on_step:
            on_step(sim)
        if abs(E[-1] / E[0] - 1) > stop:
            err = f"|dE| > {stop:g} E0"
            break
    return np.array(E), err


def growth_rate(h, E):
    """Exponential rate [1/s] of |E/E0 - 1| over its last monotone climb from 1e-4 to 1 (nan if none)."""
    a = np.abs(E / E[0] - 1)
    t = h * np.arange(len(a))
    below = np.flatnonzero(a < 1e-4)
    k = (a > 1e-4) & (a < 1.0)
    k[: below[-1] + 1 if len(below) else 0] = False
    return np.polyfit(t[k], np.log(a[k]), 1)[0] if k.sum() > 5 else float("nan")


def frequencies(sec, n=N, dim=2):
    m0 = make(n=n, sec=sec, curvature=(0, 0, 0), spin=(0, 0, 0), dim=dim)
    f = np.array([d["frequency"] for d in rod_modes(m0, count=100000, method="dense")])
    return f[f > 1e-3 * f.max()]  # drop the rigid-body modes


def fmt_err(err):
    return err if err else "runs"


# ---------------------------------------------------------------------------------------------- A, B


def table_a():
    print("\nA. Energy error against the step (base case, planar, 800 steps; wmax = highest linear frequency)")
    wmax = frequencies(section())[-1]
    print(f"   wmax = {wmax:.0f} rad/s;  kappa = 2 /m, Omega = 2 rad/s")
    print("   h [ms]   h wmax   steps   max|E/E0-1|   rate [1/s]   outcome")
    for h in 1e-3 * np.array([2.0, 2.83, 3.36, 4.0, 5.0, 6.73, 8.0, 9.5, 11.3]):
        E, err = run(make(h=h), h, 800)
        print(f"   {h * 1e3:6.2f}   {h * wmax:6.1f}   {len(E) - 1:5d}   {np.abs(E / E[0] - 1).max():11.2e}   "
              f"{growth_rate(h, E):9.2f}   {fmt_err(err)}", flush=True)


def h_star(steps=800, tol=0.1, **kw):
    """First step on the grid 2^(k/4) ms at which the run fails or |dE| exceeds tol within `steps` steps."""
    for h in 1e-3 * 2 ** (np.arange(-8, 26) / 4):
        E, err = run(make(h=h, **kw), h, steps, stop=tol)
        if err:
            return h
    return float("inf")


def table_b():
    print("\nB. Threshold step h* (first failure, |dE| > 0.1 or a solver error within 800 steps; grid ratio 2^(1/4))")
    print("   case                       h* [ms]   w_shear   w_axial   wmax     h* wmax   h* w_shear")
    rows = [("base (r = 1 cm, N = 50)", {}),
            ("N = 100", dict(n=100)),
            ("rotary inertia x100", dict(sec=section(inertia_factor=100))),
            ("shear+stretch x0.01", dict(sec=section(shear_factor=0.01))),
            ("no spin", dict(spin=(0, 0, 0))),
            ("spin 8 rad/s", dict(spin=(0, 0, 8.0))),
            ("kappa 4 /m", dict(curvature=(0, 0, 4.0))),
            ("r = 2 cm  (EA L^2/EI = 1e4)", dict(sec=section(radius=0.02))),
            ("r = 2 mm  (EA L^2/EI = 1e6)", dict(sec=section(radius=0.002)))]
    for name, kw in rows:
        sec, n = kw.get("sec", section()), kw.get("n", N)
        f = frequencies(sec, n)
        ws = math.sqrt(sec["shear_stiffness"] / sec["rotary_inertia"])
        wa = 2 * math.sqrt(sec["axial_stiffness"] / sec["mass_per_length"]) * n
        hs = h_star(**kw)
        print(f"   {name:27s} {hs * 1e3:7.2f}   {ws:7.0f}   {wa:7.0f}   {f[-1]:6.0f}   {hs * f[-1]:7.1f}   {hs * ws:7.1f}",
              flush=True)


# ---------------------------------------------------------------------------------------------- C, D


def table_c():
    h = H_BAND
    print(f"\nC. Which ingredients are needed (h = {h * 1e3:g} ms, h wmax = 31, 1500 steps)")
    print("   case                                              steps   max|E/E0-1|   rate [1/s]   outcome")
    cases = [("linear: arc kappa 1e-3, no spin", dict(curvature=(0, 0, 1e-3), spin=(0, 0, 0))),
             ("straight, spin 2 rad/s about z", dict(curvature=(0, 0, 0))),
             ("straight, spin about its axis, 0.5 rad/step (3D)", dict(curvature=(0, 0, 0), spin=(100.0, 0, 0), dim=3)),
             ("arc kappa 0.5, no spin", dict(curvature=(0, 0, 0.5), spin=(0, 0, 0))),
             ("arc kappa 1, no spin", dict(curvature=(0, 0, 1.0), spin=(0, 0, 0))),
             ("arc kappa 2, no spin", dict(spin=(0, 0, 0))),
             ("arc kappa 4, no spin", dict(curvature=(0, 0, 4.0), spin=(0, 0, 0))),
             ("arc kappa 2, spin 2 about z, planar model", {}),
             ("arc kappa 2, spin 2 about z, 3D model", dict(dim=3)),
             ("arc kappa 2, spin (1, 1, 1.4) rad/s, 3D", dict(spin=(1.0, 1.0, 1.4), dim=3))]
    for name, kw in cases:
        E, err = run(make(h=h, **kw), h, 1500)
        print(f"   {name:48s}  {len(E) - 1:5d}   {np.abs(E / E[0] - 1).max():11.2e}   {growth_rate(h, E):9.2f}   "
              f"{fmt_err(err)}", flush=True)


def table_d():
    h = H_BAND
    print(f"\nD. Where the energy goes (base case, 3D model, h = {h * 1e3:g} ms): kinetic energy [J] of the linear modes of")
    print("   the straight rod, by frequency band (momenta seen in the body frames), and the frame rotational KE")
    m = make(h=h, dim=3)
    m0 = make(h=h, curvature=(0, 0, 0), spin=(0, 0, 0), dim=3)
    modes, X = rod_modes(m0, count=100000, vectors=True, method="dense")
    f = np.array([d["frequency"] for d in modes])
    bands = [(0, 1.0, "rigid"), (1.0, 100, "<100"), (100, 1000, "1e2-1e3"), (1000, 3000, "1e3-3e3"),
             (3000, 5900, "3e3-5.9e3"), (5900, 1e9, ">5.9e3")]
    print("   t [s]   E/E0-1     frames' KE " + "".join(f"{lab:>10s}" for *_, lab in bands) + "   top modes (w, h w, KE share)")
    E0 = [None]

    def probe(sim):
        st = sim.state
        if st.n % 40 and st.n < 385:
            return
        Lam, r, _ = unpack_level(st.q[m.rod_q], m.N)
        pp = st.p[m.rod_p]
        p = pp[: 3 * (m.N + 1)].reshape(-1, 3)
        Pi = pp[3 * (m.N + 1):].reshape(-1, 3)
        eta = X.T @ np.concatenate([np.einsum("nji,nj->ni", Lam, p), Pi], 1)[m.rod.mask]
        ke = 0.5 * eta ** 2
        E = sim.monitors()["energy"]
        E0[0] = E0[0] or sim_e0
        krot = 0.5 * np.sum(Pi * Pi / m.rod.node_inertia)
        stiff = np.argsort(ke * (f > 1000))[::-1][:3]
        top = ", ".join(f"{f[i]:.0f} ({h * f[i]:.1f}, {ke[i] / ke[f > 1000].sum():.0%})" for i in stiff)
        print(f"   {st.t:5.2f}  {E / sim_e0 - 1:+8.1e}  {krot:9.1e}  " +
              "".join(f"{ke[(f >= a) & (f < b)].sum():10.1e}" for a, b, _ in bands) + "   " + top, flush=True)

    sim_e0 = Simulation(m, h=h).monitors()["energy"]
    run(m, h, 400, on_step=probe)


# ---------------------------------------------------------------------------------------------- E


class PlanarRod:
    """The same semi-discrete planar rod in exact-angle coordinates q_j = (x_j, y_j, theta_j), constant mass.

    Strains per element: kappa = dtheta/ds (or 2 tan(dtheta/2)/ds: the Cayley chart of varint),
    Gamma = 1/2 (R_j + R_j+1)^T dr/ds.  One-step schemes (position-momentum form):
      strain-midpoint     varint's discrete Lagrangian: p_n = M dq/h + h/2 B(q_n)^T s,  p_n+1 = M dq/h - h/2 B(q_n+1)^T s
      implicit-midpoint   dq = h M^-1 (p_n + p_n+1)/2,  p_n+1 - p_n = -h B(qm)^T C eps(qm),  qm = (q_n + q_n+1)/2
      energy-conserving   p_n+1 - p_n = -h Bbar^T s,  Bbar = int_0^1 B(q_n + t dq) dt (Gauss, 5 points),
    with s = C (eps_n + eps_n+1)/2; Bbar dq = eps_n+1 - eps_n makes the energy change exactly zero.
    """

    def __init__(self, model, cayley):
        rod = model.rod
        sec = rod.section
        self.N, self.ds, self.cayley = model.N, model.ds, cayley
        self.C = np.array([sec.EI, sec.EA, sec.kGA])
        w = rod.w
        self.M = np.stack([sec.rhoA * w, sec.rhoA * w, sec.rhoI * w], 1)
        th = np.arctan2(rod.Lam0[:, 1, 0], rod.Lam0[:, 0, 0])
        self.q0 = np.concatenate([rod.r0[:, :2], th[:, None]], 1)
        self.p0 = self.M * np.concatenate([rod.v0[:, :2], np.full((self.N + 1, 1), rod.spin[2])], 1)

    def strains(self, q):
        x, y, th = q[..., 0], q[..., 1], q[..., 2]
        dth = th[..., 1:] - th[..., :-1]
        kap = (2 * np.tan(dth / 2) if self.cayley else dth) / self.ds
        dx, dy = (x[..., 1:] - x[..., :-1]) / self.ds, (y[..., 1:] - y[..., :-1]) / self.ds
        c = 0.5 * (np.cos(th[..., :-1]) + np.cos(th[..., 1:]))
        s = 0.5 * (np.sin(th[..., :-1]) + np.sin(th[..., 1:]))
        return np.stack([kap, c * dx + s * dy - 1.0, -s * dx + c * dy], -1)

    def force(self, q, sig):
        """ds B(q)^T sig: the generalised force of the element stresses sig (bending moment, n1, n2)."""
        x, y, th = q[..., 0], q[..., 1], q[..., 2]
        dth = th[..., 1:] - th[..., :-1]
        dk = 1 / np.cos(dth / 2) ** 2 if self.cayley else np.ones_like(dth)
        dx, dy = x[..., 1:] - x[..., :-1], y[..., 1:] - y[..., :-1]
        ca, sa, cb, sb = np.cos(th[..., :-1]), np.sin(th[..., :-1]), np.cos(th[..., 1:]), np.sin(th[..., 1:])
        c, s = 0.5 * (ca + cb), 0.5 * (sa + sb)
        Mb, n1, n2 = sig[..., 0], sig[..., 1], sig[..., 2]
        F = np.zeros(np.broadcast_shapes(q.shape, sig.shape[:-2] + q.shape[-2:]))
        fx, fy = c * n1 - s * n2, s * n1 + c * n2
        F[..., 1:, 0] += fx
        F[..., :-1, 0] -= fx
        F[..., 1:, 1] += fy
        F[..., :-1, 1] -= fy
        F[..., :-1, 2] += 0.5 * ((-sa * dx + ca * dy) * n1 + (-ca * dx - sa * dy) * n2) - Mb * dk
        F[..., 1:, 2] += 0.5 * ((-sb * dx + cb * dy) * n1 + (-cb * dx - sb * dy) * n2) + Mb * dk
        return F

    def energy(self, q, p):
        e = self.strains(q)
        return 0.5 * np.sum(p * p / self.M) + 0.5 * self.ds * np.sum(self.C * e * e)

    def residual(self, q1, q0, p0, h, scheme):
        dq = q1 - q0
        if scheme == "implicit-midpoint":
            qm = 0.5 * (q0 + q1)
            return self.M * dq / h - p0 + 0.5 * h * self.force(qm, self.C * self.strains(qm))
        sig = self.C * 0.5 * (self.strains(q0) + self.strains(q1))
        if scheme == "strain-midpoint":
            return self.M * dq / h - p0 + 0.5 * h * self.force(q0, sig)
        g, w = np.polynomial.legendre.leggauss(5)
        F = sum(wi * 0.5 * self.force(q0 + 0.5 * (gi + 1) * dq, sig) for gi, wi in zip(g, w))
        return self.M * dq / h - p0 + 0.5 * h * F

    def step(self, q0, p0, h, scheme, guess):
        n = q0.size
        z = guess.ravel().copy()
        eps = 1e-7 * max(1.0, np.abs(z).max())
        D = np.eye(n) * eps  # batched central-difference Jacobian, once per step, then chord iterations
        Rp = self.residual((z + D).reshape((n,) + q0.shape), q0, p0, h, scheme)
        Rm = self.residual((z - D).reshape((n,) + q0.shape), q0, p0, h, scheme)
        lu = sla.lu_factor(((Rp - Rm).reshape(n, n) / (2 * eps)).T)
        for _ in range(60):
            dz = sla.lu_solve(lu, -self.residual(z.reshape(q0.shape), q0, p0, h, scheme).ravel())
            z += dz
            if np.abs(dz).max() < 1e-13 * max(1.0, np.abs(z).max()):
                break
        else:
            raise RuntimeError("Newton did not converge")
        q1 = z.reshape(q0.shape)
        if scheme == "strain-midpoint":
            sig = self.C * 0.5 * (self.strains(q0) + self.strains(q1))
            return q1, self.M * (q1 - q0) / h - 0.5 * h * self.force(q1, sig)
        return q1, 2 * self.M * (q1 - q0) / h - p0

    def run(self, h, steps, scheme, stop=10.0):
        q, p = self.q0.copy(), self.p0.copy()
        E = [self.energy(q, p)]
        guess, err = q + h * p / self.M, None
        for _ in range(steps):
            try:
                q1, p1 = self.step(q, p, h, scheme, guess)
            except (RuntimeError, np.linalg.LinAlgError, ValueError) as exc:
                err = str(exc)
                break
            guess, q, p = 2 * q1 - q, q1, p1
            E.append(self.energy(q, p))
            if not abs(E[-1] / E[0] - 1) < stop:
                err = f"|dE| > {stop:g} E0"
                break
        return np.array(E), err


def table_e():
    h, steps = H_BAND, 500
    print(f"\nE. The same planar rod outside varint (h = {h * 1e3:g} ms, {steps} steps): chart and scheme")
    print("   scheme                                  steps   max|E/E0-1|   rate [1/s]   outcome")
    m = make(h=h)
    E, err = run(m, h, steps)
    print(f"   varint (Cayley chart, strain midpoint)  {len(E) - 1:5d}   {np.abs(E / E[0] - 1).max():11.2e}   "
          f"{growth_rate(h, E):9.2f}   {fmt_err(err)}", flush=True)
    for cayley, scheme in ((True, "strain-midpoint"), (False, "strain-midpoint"), (False, "implicit-midpoint"),
                           (False, "energy-conserving")):
        E, err = PlanarRod(m, cayley).run(h, steps, scheme)
        name = f"{'Cayley' if cayley else 'angle'}, {scheme}"
        print(f"   {name:38s}  {len(E) - 1:5d}   {np.abs(E / E[0] - 1).max():11.2e}   {growth_rate(h, E):9.2f}   "
              f"{fmt_err(err)}", flush=True)


if __name__ == "__main__":
    t0 = time.perf_counter()
    quick = "--quick" in sys.argv
    for table in ((table_a, table_c, table_e) if quick else (table_a, table_b, table_c, table_d, table_e)):
        table()
    print(f"\n(wall time {time.perf_counter() - t0:.0f} s)")
