"""The hard cases of docs/theory.md §12 with and without the inextensible, unshearable constraint (§9a).

PyElastica's benchmark section (solid, r = 1 cm, E = 1 MPa), free, released from an arc while spinning:
the shearable midpoint rod blows up in a band of steps around h = 4-5 ms (resonance of its unresolved
shear-rotation modes).  With `rod.constraint = "inextensible_unshearable"` those modes are absent.  For
each case and step: max |E/E0 - 1| over the run and how it ended.

Run: python scripts/rod_constraint_hard_cases.py [--steps 10000]   (numbers in docs/theory.md §9a)
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


def run(model, h, steps):
    sim = Simulation(model, h=h)
    E0 = sim.monitors()["energy"]
    worst = 0.0
    t0 = time.perf_counter()
    for n in range(steps):
        try:
            sim.step()
        except SolverError as exc:
            return worst, f"failed at step {n + 1}: {str(exc).split(';')[0].split(': ', 1)[-1][:60]}", time.perf_counter() - t0
        worst = max(worst, abs(sim.monitors()["energy"] / E0 - 1))
        if worst > 10:
            return worst, f"|dE| > 10 E0 at step {n + 1}", time.perf_counter() - t0
    return worst, "runs", time.perf_counter() - t0


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--steps-list", default="0.004,0.005,0.008")
    args = ap.parse_args()
    hs = [float(x) for x in args.steps_list.split(",")]
    print(f"| case | h [ms] | shearable: max abs(E/E0-1) | outcome | constrained: max abs(E/E0-1) | outcome | wall s |")
    print("|---|---|---|---|---|---|---|")
    for name, kw in CASES.items():
        for h in hs:
            e1, o1, _ = run(make(h=h, **kw), h, args.steps)
            e2, o2, w2 = run(make(h=h, constraint="inextensible_unshearable", **kw), h, args.steps)
            print(f"| {name} | {h * 1e3:.0f} | {e1:.2g} | {o1} | {e2:.2g} | {o2} | {w2:.1f} |", flush=True)


if __name__ == "__main__":
    main()
