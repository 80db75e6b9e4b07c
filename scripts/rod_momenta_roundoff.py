"""The midpoint rod's momenta over long runs of the base hard case (docs/theory.md §9, "Momenta to round-off").

Run:  python scripts/rod_momenta_roundoff.py [--steps 5000] [--h 2e-3] [--dim 2 3] [--no-polish] [--case 2]
      (--case K: case K of scripts/rod_constraint_hard_cases.py CASES instead of the base case, e.g. 2 = spin 8 rad/s,
      3 = slender r = 2 mm; --dim then only chooses the model's dimension)

Case: docs/theory.md §12's base hard case (PyElastica's section, free arc kappa = 2 /m spinning at 2 rad/s about z,
N = 50; 3D: arc about z and y), stepped by Simulation (the compiled FastRodStep).  Prints the largest changes over
the run of the linear momentum (times L) and the angular momentum, relative to |J0| (the spin's), the largest
energy error, Newton iterations per step and the wall time; --no-polish switches the rigid polish of the step's
solution off (FastRodStep.ci[10] = 0).  The "before" row of the theory's table is this script at commit 7e271c0.
"""

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from rod_stiff_diagnosis import make  # noqa: E402

from varint import Simulation  # noqa: E402
from varint.errors import SolverError  # noqa: E402


def run(dim, steps, h, polish=True, case=None):
    kw = dict(dim=3, curvature=(0, 1.0, 2.0)) if dim == 3 else {}
    if case is not None:
        from rod_constraint_hard_cases import CASES

        kw = dict(list(CASES.values())[case], dim=dim)
    model = make(h=h, **kw)
    sim = Simulation(model, h=h)
    if sim.stepper.compiled is not None and not polish:
        sim.stepper.compiled.ci[10] = 0
    m0 = sim.monitors()
    P0, J0, E0 = np.asarray(m0["linear_momentum"]), np.asarray(m0["angular_momentum"]), m0["energy"]
    scale = np.linalg.norm(J0)
    dP = dJ = dE = 0.0
    its = 0
    outcome = "runs"
    t0 = time.perf_counter()
    n = 0
    for n in range(1, steps + 1):
        try:
            sim.step()
        except SolverError as exc:
            outcome = f"fails at step {n}: {str(exc)[:70]}"
            break
        its += sim.stats.iterations
        mo = sim.monitors()
        dP = max(dP, float(np.abs(np.asarray(mo["linear_momentum"]) - P0).max()) * model.rod.L / scale)
        dJ = max(dJ, float(np.abs(np.asarray(mo["angular_momentum"]) - J0).max()) / scale)
        dE = max(dE, abs(mo["energy"] / E0 - 1.0))
    return dict(dP=dP, dJ=dJ, dE=dE, its=its / max(n, 1), wall=time.perf_counter() - t0, outcome=outcome)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--steps", type=int, default=5000)
    ap.add_argument("--h", type=float, default=2e-3)
    ap.add_argument("--dim", type=int, nargs="+", default=[2, 3])
    ap.add_argument("--no-polish", action="store_true")
    ap.add_argument("--case", type=int, default=None, help="a case of rod_constraint_hard_cases.CASES by index")
    args = ap.parse_args()
    print("| model | h [ms] | steps | rigid polish | max dP L/|J0| | max dJ/|J0| | max |E/E0-1| | iterations/step | wall s | outcome |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for dim in args.dim:
        r = run(dim, args.steps, args.h, not args.no_polish, args.case)
        print(f"| {'planar' if dim == 2 else '3D'} | {args.h * 1e3:g} | {args.steps} | {'no' if args.no_polish else 'yes'} "
              f"| {r['dP']:.2e} | {r['dJ']:.2e} | {r['dE']:.3e} | {r['its']:.2f} | {r['wall']:.0f} | {r['outcome']} |",
              flush=True)


if __name__ == "__main__":
    main()
