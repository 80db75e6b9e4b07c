"""The hard cases of docs/theory.md §12 with and without the inextensible, unshearable constraint (§9a).

PyElastica's benchmark section (solid, r = 1 cm, E = 1 MPa), free, released from an arc while spinning:
the shearable midpoint rod blows up in a band of steps around h = 4-5 ms (resonance of its unresolved
shear-rotation modes).  With `rod.constraint = "inextensible_unshearable"` those modes are absent.  For
each case and step: max |E/E0 - 1| over the run and how it ended.

Run: python scripts/rod_constraint_hard_cases.py [--steps 10000]   (numbers in docs/theory.md §9a)
     python scripts/rod_constraint_hard_cases.py --long --steps 100000 --steps-list 0.005   (the constrained rod's
     long runs with its momenta; docs/validation.md)
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from rod_stiff_diagnosis import make, section  # noqa: E402

from varint import Simulation  # noqa: E402
from varint.errors import SolverError  # noqa: E402

CASES = {
    "base: free arc kappa = 2, spin 2 rad/s, planar, N = 50": dict(),
    "3D, arc about z and y, spin about z": dict(dim=3, curvature=(0, 1.0, 2.0)),
    "spin 8 rad/s": dict(spin=(0, 0, 8.0)),
    "slender r = 2 mm (EA L^2/EI = 1e6)": dict(sec=section(radius=0.002)),
}


def run(model, h, steps, momenta=None):
    """max |E/E0 - 1| over the run, its outcome and wall time; with ``momenta`` (a dict) also the largest
    changes of the linear and angular momenta, relative to |J0| / L and |J0| (the spin's)."""
    sim = Simulation(model, h=h)
    m0 = sim.monitors()
    E0, P0, J0 = m0["energy"], np.asarray(m0["linear_momentum"]), np.asarray(m0["angular_momentum"])
    scale = np.linalg.norm(J0)
    worst = dP = dJ = 0.0
    t0 = time.perf_counter()
    outcome = "runs"
    for n in range(steps):
        try:
            sim.step()
        except SolverError as exc:
            outcome = f"failed at step {n + 1}: {str(exc).split(';')[0].split(': ', 1)[-1][:60]}"
            break
        mo = sim.monitors()
        worst = max(worst, abs(mo["energy"] / E0 - 1))
        if momenta is not None:
            dP = max(dP, float(np.max(np.abs(np.asarray(mo["linear_momentum"]) - P0))) * model.rod.L / scale)
            dJ = max(dJ, float(np.max(np.abs(np.asarray(mo["angular_momentum"]) - J0))) / scale)
        if worst > 10:
            outcome = f"|dE| > 10 E0 at step {n + 1}"
            break
    if momenta is not None:
        momenta.update(P=dP, J=dJ)
    return worst, outcome, time.perf_counter() - t0


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--steps-list", default="0.004,0.005,0.008")
    ap.add_argument("--long", action="store_true", help="the constrained rod only, with the momenta (issue's 1e5-step runs)")
    args = ap.parse_args()
    hs = [float(x) for x in args.steps_list.split(",")]
    if args.long:
        print(f"| case | h [ms] | steps | constrained: max abs(E/E0-1) | max dP L/abs(J0) | max dJ/abs(J0) | outcome | wall s |")
        print("|---|---|---|---|---|---|---|---|")
        for name, kw in CASES.items():
            for h in hs:
                mom = {}
                e2, o2, w2 = run(make(h=h, constraint="inextensible_unshearable", **kw), h, args.steps, momenta=mom)
                print(f"| {name} | {h * 1e3:.0f} | {args.steps} | {e2:.2g} | {mom['P']:.1e} | {mom['J']:.1e} | {o2} | {w2:.0f} |",
                      flush=True)
        return
    print(f"| case | h [ms] | shearable: max abs(E/E0-1) | outcome | constrained: max abs(E/E0-1) | outcome | wall s |")
    print("|---|---|---|---|---|---|---|")
    for name, kw in CASES.items():
        for h in hs:
            e1, o1, _ = run(make(h=h, **kw), h, args.steps)
            e2, o2, w2 = run(make(h=h, constraint="inextensible_unshearable", **kw), h, args.steps)
            print(f"| {name} | {h * 1e3:.0f} | {e1:.2g} | {o1} | {e2:.2g} | {o2} | {w2:.1f} |", flush=True)


if __name__ == "__main__":
    main()
