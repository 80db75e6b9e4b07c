"""Work-precision for the smooth pulse: error reached against wall time, varint's midpoint and
trapezoidal steps next to scipy's solve_ivp (DOP853, Radau) on the same semi-discrete equations.

The semi-discrete system is the lattice Lagrangian's Euler-Lagrange ODE: dq/dt = p / M,
dp/dt = -B_q^T grad U(config(q)).  Every method integrates exactly these equations from the same
initial state; the error is max |q(T) - q_ref(T)| / (L / M) against a DOP853 reference at rtol 1e-13.
Also writes docs/work_precision.png.  Run:  python scripts/work_precision.py
"""

import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.integrate import solve_ivp

from varint import Simulation, build_model
from varint.scene.standard import gas_scene, scene_of

ROOT = Path(__file__).resolve().parent.parent

M_PARCELS = 64
T_END = 4e-3
PULSE = [{"field": "pressure", "shape": "gaussian", "amplitude": 5e3, "center": 0.5, "width": 0.1}]


def model_for(h, scheme):
    return build_model(scene_of(gas_scene(nodes=M_PARCELS + 1, parcels=M_PARCELS, h=h, perturbation=PULSE, scheme=scheme)))


def rhs_factory(model):
    tube = model.tube  # the s, R blocks (varint.terms.tube.TubePart); no algebraic unknowns in this scene
    Bq = tube.B[:, : tube.nq]
    Minv = 1.0 / tube.mass
    nq = tube.nq

    def rhs(t, y):
        q, p = y[:nq], y[nq:]
        g = tube.gradient(tube.config(q))
        return np.concatenate([Minv * p, -(Bq.T @ g)])

    def jac(t, y):
        q = y[:nq]
        K = (Bq.T @ tube.hessian(tube.config(q)) @ Bq).tocsr()
        Z = sp.csr_matrix((nq, nq))
        return sp.bmat([[Z, sp.diags(Minv)], [-K, Z]]).tocsc()

    return rhs, jac


def run_varint(h, scheme):
    model = model_for(h, scheme)
    sim = Simulation(model)
    n = int(round(T_END / h))
    t0 = time.perf_counter()
    for _ in range(n):
        sim.step()
    return time.perf_counter() - t0, sim.state.q[model.tube_q].copy()


def run_scipy(method, rtol, model):
    rhs, jac = rhs_factory(model)
    y0 = np.concatenate([model.tube.q_init, model.tube.p_init])
    kw = {"jac": jac} if method == "Radau" else {}
    t0 = time.perf_counter()
    sol = solve_ivp(rhs, (0.0, T_END), y0, method=method, rtol=rtol, atol=rtol * 1e-3, **kw)
    return time.perf_counter() - t0, sol.y[: model.tube.nq, -1], sol.nfev


def main():
    model = model_for(1e-6, "midpoint")
    scale = 1.0 / M_PARCELS
    _, q_ref, _ = run_scipy("DOP853", 1e-13, model)
    run_varint(1e-5, "midpoint")  # compile before timing
    rows = []
    for scheme in ("midpoint", "trapezoidal"):
        for h in (4e-5, 2e-5, 1e-5, 5e-6, 2.5e-6, 1.25e-6):
            if scheme == "trapezoidal" and h > 1.2e-5:
                continue  # beyond the explicit stability limit of the stiffest lattice mode
            wall, q = run_varint(h, scheme)
            rows.append((f"varint {scheme}", f"h = {h:.3g}", wall, np.max(np.abs(q - q_ref)) / scale))
    for method, tols in (("DOP853", (1e-4, 1e-6, 1e-8, 1e-10)), ("Radau", (1e-3, 1e-5, 1e-7, 1e-9))):
        for rtol in tols:
            wall, q, nfev = run_scipy(method, rtol, model)
            rows.append((f"scipy {method}", f"rtol = {rtol:g} ({nfev} f-evals)", wall, np.max(np.abs(q - q_ref)) / scale))
    print(f"\n### Work-precision: smooth pulse in the rubber tube, {M_PARCELS} parcels, T = {T_END} s\n")
    print("error = max |s_k(T) - s_k,ref(T)| / parcel length; reference: DOP853 at rtol 1e-13 on the same ODE\n")
    print("| method | setting | wall s | error |")
    print("|---|---|---|---|")
    for name, setting, wall, err in rows:
        print(f"| {name} | {setting} | {wall:.3f} | {err:.2e} |")
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(6, 4.2), constrained_layout=True)
        for name in dict.fromkeys(r[0] for r in rows):
            pts = sorted((w, e) for n, _, w, e in rows if n == name)
            ax.loglog([p[0] for p in pts], [p[1] for p in pts], "o-", label=name)
        ax.set_xlabel("wall time [s]")
        ax.set_ylabel("error / parcel length")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
        ax.set_title("work-precision, smooth pulse (same semi-discrete equations)", fontsize=9)
        fig.savefig(ROOT / "docs" / "work_precision.png", dpi=110)
    except ImportError:
        pass


def long_time_energy(T_long=0.2):
    """Energy error over a long run: what the variational structure buys."""
    print(f"\n### Energy over a long run (same scene, T = {T_long} s, ~{int(T_long * 940 / 6.28)} low-branch periods)\n")
    print("energy error normalised by the wave energy (the largest kinetic energy of the run), not by the")
    print("total energy, which is dominated by the gas's internal energy at rest\n")
    print("| method | setting | wall s | max energy error / wave energy | same, last 10 % of the run |")
    print("|---|---|---|---|---|")
    for scheme, h in (("midpoint", 1e-5), ("trapezoidal", 5e-6)):
        model = model_for(h, scheme)
        sim = Simulation(model)
        n = int(round(T_long / h))
        E = np.empty(n)
        K = np.empty(n)
        t0 = time.perf_counter()
        for i in range(n):
            sim.step()
            mo = sim.monitors()
            E[i], K[i] = mo["energy"], mo["kinetic_energy"]
        wall = time.perf_counter() - t0
        err = np.abs(E - E[0]) / K.max()
        print(f"| varint {scheme} | h = {h:g} | {wall:.2f} | {err.max():.2e} | {err[-n // 10:].max():.2e} |")
    model = model_for(1e-5, "midpoint")
    rhs, jac = rhs_factory(model)
    tube = model.tube
    Minv = 1.0 / tube.mass
    nq = tube.nq
    y0 = np.concatenate([tube.q_init, tube.p_init])
    for method, rtol in (("DOP853", 1e-6), ("DOP853", 1e-9), ("Radau", 1e-6)):
        kw = {"jac": jac} if method == "Radau" else {}
        t0 = time.perf_counter()
        sol = solve_ivp(rhs, (0.0, T_long), y0, method=method, rtol=rtol, atol=rtol * 1e-3, dense_output=False, **kw)
        wall = time.perf_counter() - t0
        K = np.array([0.5 * np.dot(Minv * y[nq:], y[nq:]) for y in sol.y.T])
        E = K + np.array([tube.potential(tube.config(y[:nq])) for y in sol.y.T])
        err = np.abs(E - E[0]) / K.max()
        k = max(1, len(err) // 10)
        print(f"| scipy {method} | rtol = {rtol:g} | {wall:.2f} | {err.max():.2e} | {err[-k:].max():.2e} |")


if __name__ == "__main__":
    main()
    long_time_energy()
