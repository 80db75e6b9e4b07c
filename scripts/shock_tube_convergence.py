"""Shock tubes with [shock_capturing] against the exact Riemann solution (varint.exact.shocks.RiemannSolution).

Sod, (rho, u, p) = (1, 0, 1) | (0.125, 0, 0.1) at t = 0.2, and two strong tubes (pressure ratios 100 and
1e5, the latter Toro's test 3 at t = 0.012) on [0, 1], diaphragm at 0.5, closed ends (no wave reaches
them by the final time), gamma = 1.4, a rigid uniform tube of cross-section 1 m^2.  For N = 100 ... 3200
parcels: the density's L1 error, the observed rate between successive N, the wall time of the steps
(model building and the first numba compilation excluded), the relative energy error at the end, the
minimum density and pressure, and the Newton iterations per step.  Prints a markdown table.

Parcels have equal length at t = 0 (that is how varint.terms.tube places the labels): each side of the
diaphragm is resolved by N/2 parcels, whatever its density.

Run:  python scripts/shock_tube_convergence.py [--cases sod,ratio100,ratio1e5] [--max 3200] [--cfl 0.5] [--limiter]
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from varint import Simulation, build_model, parse_scene
from varint.analysis.shock_measure import density_l1
from varint.exact.shocks import RiemannSolution

GAMMA = 1.4
#: the density's L1 error is integrated on SAMPLES - 1 equal sub-intervals of [0, 1] (density_l1)
SAMPLES = 400001
CASES = {
    "sod": ((1.0, 0.0, 1.0), (0.125, 0.0, 0.1), 0.2),
    "ratio100": ((1.0, 0.0, 10.0), (0.125, 0.0, 0.1), 0.1),
    "ratio1e5": ((1.0, 0.0, 1000.0), (1.0, 0.0, 0.01), 0.012),
}

SCENE = """title = "shock tube"
[tube]
length = 1.0
nodes = 3
radius = {radius!r}
[fluid]
model = "ideal-gas"
gamma = {gamma!r}
density = {rl!r}
pressure = {pl!r}
velocity = {ul!r}
parcels = {M}
[[fluid.initial]]
from = 0.5
to = 1.0
density = {rr!r}
pressure = {pr!r}
velocity = {ur!r}
[time]
step = {h!r}
end = {end!r}
[shock_capturing]
quadratic = {cQ!r}
linear = {cL!r}
"""


def scene_text(M, left, right, end, cfl, cQ, cL):
    """The scene of one run; h = cfl * (1/M) / (the largest initial sound speed + |u|), rounded to hit ``end``."""
    cmax = max(math.sqrt(GAMMA * s[2] / s[0]) + abs(s[1]) for s in (left, right))
    n = int(math.ceil(end * M * cmax / cfl))
    return SCENE.format(radius=1.0 / math.sqrt(math.pi), gamma=GAMMA, rl=left[0], ul=left[1], pl=left[2], rr=right[0],
                        ur=right[1], pr=right[2], M=M, h=end / n, end=end, cQ=cQ, cL=cL), n


def contact_cells(s, rho, exact, t, margin=0.05):
    """Parcels near the contact whose density lies strictly inside its jump (by ``margin`` of the jump).

    "Near": centres closer to the exact contact than half the distance to the next wave.  A Lagrangian
    contact sits on a label, so this counts only the parcels the start-up error ("wall heating") leaves
    off the two plateaus.
    """
    g = exact.gamma
    xc = 0.5 + exact.u_star * t
    rl, ul, pl = exact.left
    c_star = math.sqrt(g * exact.p_star / exact.rho_star_left)
    left_wave = (exact.shock_speeds()[0] if exact.left_wave == "shock" else exact.u_star - c_star)
    right_wave = exact.shock_speeds()[1] if exact.right_wave == "shock" else exact.u_star + math.sqrt(g * exact.p_star / exact.rho_star_right)
    w = 0.5 * t * min(exact.u_star - left_wave, right_wave - exact.u_star)
    centres = 0.5 * (s[1:] + s[:-1])
    lo, hi = sorted((exact.rho_star_left, exact.rho_star_right))
    d = hi - lo
    near = np.abs(centres - xc) < w
    return int(np.sum(near & (rho > lo + margin * d) & (rho < hi - margin * d)))


def run(case, M, cfl=0.5, cQ=1.0, cL=0.5, limiter=False):
    left, right, end = CASES[case]
    text, n = scene_text(M, left, right, end, cfl, cQ, cL)
    model = build_model(parse_scene(text))
    model.forces[0].limiter = limiter  # Christensen's limiter (varint.terms.shock_capturing.limited)
    sim = Simulation(model)
    E0 = sim.monitors()["energy"]
    t0 = time.perf_counter()
    for _ in range(n):
        sim.step()
    wall = time.perf_counter() - t0
    mon = sim.monitors()
    t, st = model.tube, sim.state
    cfg = t.config(np.concatenate([st.q[model.tube_q], st.lam]))
    rho, p, _ = t.fluid_fields(cfg, st.p[model.tube_p])
    exact = RiemannSolution(left, right, GAMMA)
    return {"case": case, "N": M, "steps": n, "l1": density_l1(cfg.s, rho, exact, end, SAMPLES), "wall": wall,
            "energy": abs(mon["energy"] - E0) / abs(E0), "rho_min": float(rho.min()), "p_min": float(p.min()),
            "iterations": sim.stats.total_iterations / n, "contact": contact_cells(cfg.s, rho, exact, end)}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", default="sod,ratio100,ratio1e5")
    ap.add_argument("--max", type=int, default=3200)
    ap.add_argument("--cfl", type=float, default=0.5)
    ap.add_argument("--quadratic", type=float, default=1.0)
    ap.add_argument("--linear", type=float, default=0.5)
    ap.add_argument("--limiter", action="store_true", help="Christensen's limiter on the viscous pressure")
    args = ap.parse_args()
    run("sod", 20)  # compile the numba kernels outside the timings
    print(f"c_Q = {args.quadratic:g}, c_L = {args.linear:g}{', limiter' if args.limiter else ''}, CFL {args.cfl:g} "
          "on the largest initial sound speed\n")
    print("| case | N | steps | density L1 | rate | wall [s] | energy error | min rho | min p | Newton it/step | contact cells |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for case in args.cases.split(","):
        prev = None
        M = 100
        while M <= args.max:
            r = run(case, M, args.cfl, args.quadratic, args.linear, args.limiter)
            rate = "" if prev is None else f"{math.log2(prev / r['l1']):.2f}"
            print(f"| {case} | {M} | {r['steps']} | {r['l1']:.3e} | {rate} | {r['wall']:.2f} | {r['energy']:.1e} | "
                  f"{r['rho_min']:.4g} | {r['p_min']:.4g} | {r['iterations']:.1f} | {r['contact']} |", flush=True)
            prev = r["l1"]
            M *= 2


if __name__ == "__main__":
    main()
