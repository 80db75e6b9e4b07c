"""The periodic flowing pipe (varint.scene.standard.periodic_pipe_scene, tests/test_flowing_pipe.py): its space-discrete
linearisation, time-domain runs of varint against it, and the runs behind docs/theory.md §10.11 and §12 ("the flowing
lattice").

    python scripts/flowing_pipe_linear.py                 # averaged lattice linearisation vs the continuum (1 s)
    python scripts/flowing_pipe_linear.py --runs          # varint time domain vs both (about 2 min)
    python scripts/flowing_pipe_linear.py --saturation    # the nonlinear end of the flutter (about 30 s)
    python scripts/flowing_pipe_linear.py --instability   # the flow instability (docs/theory.md §12, about 5 min)

The linearisation (docs/theory.md §10.11) is written here independently of varint's kernels: by the y -> -y
symmetry of the straight state the lateral unknowns (w_j, psi_j) decouple from the axial ones, the labels
s_k = s_k0 + U t only enter through the Catmull–Rom weights N_i(s_k), and averaged over a label spacing
(labels uniform) the fluid contributes M int N N^T (mass), the gyroscopic M U int (N N'^T - N' N^T) and the
centrifugal -M U^2 int N' N'^T; the rod is the periodic Timoshenko lattice of §9 linearised (Gamma_2 =
(w_{j+1} - w_j)/ds - (psi_j + psi_{j+1})/2, Omega = (psi_{j+1} - psi_j)/ds, lumped masses).  Its eigenvalues
are compared with varint.exact.beams.flowing_pipe_waves (the continuum) and with the two-exponential fit of a
varint run.
"""

import argparse
import math
import time

import numpy as np

from varint.analysis.signals import dominant_frequency, two_frequency_fit
from varint.exact.beams import flowing_pipe_critical_speed, flowing_pipe_waves
from varint.scene.standard import (FLOWING_PIPE_DENSITY, FLOWING_PIPE_RADIUS, FLOWING_PIPE_SECTION, FLOWING_PIPE_STEP,
                                   FLOWING_PIPE_WALL, periodic_pipe_critical_speed)

from _runs import periodic_pipe_run

EI, KGA, RHOA, RHOI, M = 1.0, 400.0, 1.0, 1e-4, 1.0
K = 2.0 * math.pi


def catmull_rom(t):
    N = np.array([0.5 * (-t ** 3 + 2 * t ** 2 - t), 0.5 * (3 * t ** 3 - 5 * t ** 2 + 2),
                  0.5 * (-3 * t ** 3 + 4 * t ** 2 + t), 0.5 * (t ** 3 - t ** 2)])
    dN = np.array([0.5 * (-3 * t ** 2 + 4 * t - 1), 0.5 * (9 * t ** 2 - 10 * t), 0.5 * (-9 * t ** 2 + 8 * t + 1),
                   0.5 * (3 * t ** 2 - 2 * t)])
    return N, dN


def lattice_matrices(n_el, U, EI=EI, kGA=KGA, rhoA=RHOA, rhoI=RHOI, M=M, quad=8):
    """Mass, gyroscopic and stiffness matrices of the averaged lateral linearisation on n_el periodic elements
    (unknowns w_0..w_{N-1}, psi_0..psi_{N-1}; L = 1/2 qdot^T Mm qdot + qdot^T B q - 1/2 q^T K q)."""
    ds = 1.0 / n_el
    n = 2 * n_el
    Mm, B, Kq = np.zeros((n, n)), np.zeros((n, n)), np.zeros((n, n))
    for j in range(n_el):
        Mm[j, j], Mm[n_el + j, n_el + j] = rhoA * ds, rhoI * ds
        a, b = j, (j + 1) % n_el
        g = np.zeros(n)
        g[b] += 1 / ds
        g[a] -= 1 / ds
        g[n_el + a] -= 0.5
        g[n_el + b] -= 0.5
        o = np.zeros(n)
        o[n_el + b] += 1 / ds
        o[n_el + a] -= 1 / ds
        Kq += ds * (kGA * np.outer(g, g) + EI * np.outer(o, o))
    x, wq = np.polynomial.legendre.leggauss(quad)  # exact: the integrands are polynomials of degree <= 6
    for e in range(n_el):
        idx = [(e - 1) % n_el, e, (e + 1) % n_el, (e + 2) % n_el]
        for t, w in zip(0.5 * (x + 1), 0.5 * wq):
            Nv, dN = catmull_rom(t)
            v, d = np.zeros(n), np.zeros(n)
            for i, I in enumerate(idx):
                v[I] += Nv[i]
                d[I] += dN[i] / ds
            Mm += M * ds * w * np.outer(v, v)
            B += M * U * ds * w * np.outer(v, d)
            Kq -= M * U * U * ds * w * np.outer(d, d)
    return Mm, B, Kq


def lattice_waves(n_el, U, **kw):
    """The two bending frequencies omega of the wave (W, Psi) exp(i (k x - omega t)), k = 2 pi: the averaged
    matrices are block-circulant, so their symbols at k give a 2 x 2 quadratic eigenproblem (4 roots; the two of
    least modulus are the bending branch)."""
    Mm, B, Kq = lattice_matrices(n_el, U, **kw)
    phase = np.exp(1j * K * np.arange(n_el) / n_el)

    def symbol(A):
        return np.array([[A[a * n_el, b * n_el:(b + 1) * n_el] @ phase for b in range(2)] for a in range(2)])

    Ms, Gs, Ks = symbol(Mm), symbol(B - B.T), symbol(Kq)
    # (-omega^2 Ms - i omega Gs + Ks) Q = 0, as a first-order pencil in omega
    Z, I = np.zeros((2, 2)), np.eye(2)
    lhs = np.block([[Z, I], [Ks, -1j * Gs]])
    rhs = np.block([[I, Z], [Z, Ms]])
    from scipy.linalg import eig

    w = eig(lhs, rhs, right=False)
    low = sorted(w, key=abs)[:2]
    return tuple(sorted((complex(x) for x in low), key=lambda z: (round(z.real, 9), z.imag)))


def continuum(U):
    w = flowing_pipe_waves(K, U, EI, KGA, RHOA, RHOI, M)
    return tuple(sorted(w, key=lambda z: (round(z.real, 9), z.imag)))


def critical_speed():
    return flowing_pipe_critical_speed(K, EI, KGA, RHOA, RHOI, M)


def fmt(ws):
    return " ".join(f"{w.real:8.3f}{w.imag:+8.3f}j" for w in ws)


def table_linear():
    Uc = critical_speed()
    print(f"U_c (continuum, Timoshenko) = {Uc:.4f} m/s")
    print(f"{'U/U_c':>6} {'elements':>8}  {'lattice (averaged)':>36}  {'continuum':>36}  rel. error")
    for f in (0.0, 0.5, 0.9, 1.1, 1.6):
        ex = continuum(f * Uc)
        for n in (10, 20, 40):
            w = lattice_waves(n, f * Uc)
            err = max(abs(w[i] - ex[i]) / abs(ex[i]) for i in range(2))
            print(f"{f:6.2f} {n:8d}  {fmt(w):>36}  {fmt(ex):>36}  {err:.2e}")


def table_runs():
    Uc = periodic_pipe_critical_speed()
    print(f"{'U/U_c':>6} {'el':>3} {'amp':>6}  {'varint run':>36}  {'lattice':>36}  {'continuum':>36}  s")
    for f, n, amp, dom in ((0.5, 10, 1e-5, False), (0.5, 20, 1e-5, False), (0.9, 20, 1e-5, False),
                           (1.1, 10, 1e-6, True), (1.1, 20, 1e-6, True), (0.5, 10, 1e-3, False), (1.1, 10, 1e-3, False)):
        t0 = time.time()
        res = periodic_pipe_run(f * Uc, n + 1, 2 * n, amplitude=amp)
        h = FLOWING_PIPE_STEP
        w = (dominant_frequency(res["c"][600:], h),) if dom else two_frequency_fit(res["c"], h)
        lw, ex = lattice_waves(n, f * Uc), continuum(f * Uc)
        if dom:
            lw, ex = (max(lw, key=lambda z: z.imag),), (max(ex, key=lambda z: z.imag),)
        print(f"{f:6.2f} {n:3d} {amp:6.0e}  {fmt(w):>36}  {fmt(lw):>36}  {fmt(ex):>36}  {time.time() - t0:.0f}"
              f"  (energy {np.abs(res['energy']).max():.1e}, lateral P {res['momentum']:.1e},"
              f" axial P {res['axial_momentum']:.1e}, min mean p - p_ext {res['pressure'].min():.3g} Pa)", flush=True)


def saturation():
    Uc = periodic_pipe_critical_speed()
    area = math.pi * FLOWING_PIPE_RADIUS ** 2
    w, h = FLOWING_PIPE_WALL, FLOWING_PIPE_STEP
    R = FLOWING_PIPE_RADIUS
    stiff = w["youngs_modulus"] * w["thickness"] / (2 * R * (1 - w["poisson_ratio"] ** 2))  # -R dp/dR / 2
    for f, n in ((1.1, 10), (1.1, 20), (1.2, 10)):
        U = f * Uc
        res = periodic_pipe_run(U, n + 1, 2 * n, steps=900, amplitude=1e-3)
        i = int(np.argmin(res["pressure"]))
        dp = -M * (U * U - Uc * Uc) / area
        W = 2.0 / K * math.sqrt(-dp / stiff)
        print(f"U = {f} U_c, {n} el: min mean p - p_ext = {res['pressure'][i]:.0f} Pa at t = {i * h:.3f} s "
              f"(predicted -M (U^2 - U_c^2)/A = {dp:.0f} Pa); wave amplitude there {2 * res['amplitude'][i]:.2e} m "
              f"(predicted {W:.2e} m); at the end {2 * res['amplitude'][-1]:.2e} m", flush=True)


def _scene(U, nodes, parcels, h, steps, E=2e11, wall_model="quasistatic", fluid="incompressible"):
    """The periodic pipe of varint.scene.standard.periodic_pipe_scene at rest laterally, with the wall's model and
    Young's modulus and the liquid (incompressible or barotropic) chosen."""
    from varint.scene.text import to_toml
    from varint import parse_scene

    d = {"title": "periodic flowing pipe", "tube": {"length": 1.0, "nodes": nodes, "radius": FLOWING_PIPE_RADIUS},
         "rod": dict(FLOWING_PIPE_SECTION, dimension=2, ends={"s0": "periodic", "sL": "periodic"}),
         "wall": dict(FLOWING_PIPE_WALL, model=wall_model, youngs_modulus=E),
         "fluid": {"model": fluid, "density": FLOWING_PIPE_DENSITY, "pressure": 1e5, "parcels": parcels, "velocity": U,
                   "ends": {"s0": "periodic", "sL": "periodic"}},
         "time": {"step": h, "end": steps * h}}
    if fluid == "barotropic":
        d["fluid"]["bulk_modulus"] = 2.2e9
        d["environment"] = {"external_pressure": 1e5}
    return parse_scene(to_toml(d))


def instability():
    """Runs from rest (no lateral perturbation: round-off seeds it) of the periodic flowing pipe: the growth rate
    of the pressure spread along the tube, the energy error, and whether the pattern flips sign every step."""
    from varint import Simulation, build_model

    Uc = periodic_pipe_critical_speed()
    cases = [dict(f=0.0, n=40, P=80, h=5e-4, t=0.6), dict(f=0.5, n=40, P=80, h=5e-4, t=0.6),
             dict(f=0.5, n=40, P=80, h=1e-3, t=0.6)]
    cases += [dict(f=1.1, n=10, P=20, h=h, t=t) for h, t in ((1e-3, 0.4), (5e-4, 0.4), (2.5e-4, 0.4), (1.25e-4, 0.3),
                                                               (6.25e-5, 0.15))]
    cases += [dict(f=f, n=10, P=20, h=1.25e-4, t=0.3) for f in (0.1, 0.5)]
    cases += [dict(f=1.1, n=10, P=P, h=1.25e-4, t=0.3) for P in (10, 40)]
    cases += [dict(f=1.1, n=10, P=20, h=1.25e-4, t=0.3, **kw) for kw in (
        dict(E=2e8), dict(wall_model="dynamic"), dict(fluid="barotropic"), dict(fluid="barotropic", E=2e8))]
    cases += [dict(f=0.5, n=40, P=80, h=5e-4, t=0.6, fluid="barotropic"),
              dict(f=0.5, n=40, P=80, h=5e-4, t=0.6, fluid="barotropic", E=2e8)]
    for c in cases:
        c = dict(c)
        f, n, P, h, tend = (c.pop(k) for k in ("f", "n", "P", "h", "t"))
        steps = int(round(tend / h))
        sim = Simulation(build_model(_scene(f * Uc, n + 1, P, h, steps, **c)))
        m0 = sim.monitors()
        scale = m0["energy_fluid_kinetic"] or 1.0
        spread, err, fail, last = [], 0.0, None, []
        for i in range(steps):
            try:
                sim.step()
            except Exception:
                fail = i
                break
            p = sim.fields()["fluid/pressure"]
            spread.append(p.max() - p.min())
            last = (last + [p - p.mean()])[-2:]
            err = max(err, abs(sim.monitors()["energy"] - m0["energy"]) / scale)
        spread = np.array(spread)
        i1 = len(spread) - 1
        i0 = int(0.6 * i1)
        rate = math.log(spread[i1] / spread[i0]) / ((i1 - i0) * h) if spread[i0] > 0 else float("nan")
        flip = float(last[0] @ last[1] / (np.linalg.norm(last[0]) * np.linalg.norm(last[1]) + 1e-300))
        print(f"U = {f} U_c, {n} el, {P} parcels, h = {h:g} {c or ''}: "
              + (f"fails at t = {fail * h:.3f} s" if fail is not None else f"runs {tend} s")
              + f", pressure spread {spread[-1]:.1e} Pa growing at {rate:.0f} /s, energy error {err:.1e}"
              f" (of the flow's), step-to-step correlation of the pressure pattern {flip:+.2f}", flush=True)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", action="store_true")
    ap.add_argument("--saturation", action="store_true")
    ap.add_argument("--instability", action="store_true")
    a = ap.parse_args()
    table_linear()
    if a.runs:
        table_runs()
    if a.saturation:
        saturation()
    if a.instability:
        instability()
