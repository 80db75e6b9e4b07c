"""The coupled tube's energy-momentum step (varint/schemes/em_tube.py, TubeEMStep) now against the same step at an earlier
commit, in alternating blocks of one process (as scripts/bench_rod_step_vs_commit.py does for the rod).

Cases: the garden hose of scripts/tube_em_hard_cases.py (free, arc released spinning, dynamic linear wall) with
incompressible water, 20 and 6 elements, at h = 5 ms; a gas-filled 6-element tube spinning freely (the tests' model).
The ratio is fair on a shared machine, the absolute times are not.

Run:  python scripts/bench_tube_em.py --rev c6b4956 [--rounds 3] [--steps 20] [--cases "20 el.,6 el."]
      python scripts/bench_tube_em.py --frames      (Newton in the body frames against the spatial frames, both now)
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "scripts"))

from bench_rod_step_vs_commit import module_at  # noqa: E402


def cases():
    from tube_em_hard_cases import scene

    return {"hose, water, 20 el.": lambda: scene("liquid", 5e-3, nodes=21, scheme="energy-momentum"),
            "hose, water, 6 el.": lambda: scene("liquid", 5e-3, nodes=7, scheme="energy-momentum"),
            "hose, air, 20 el.": lambda: scene("air", 5e-3, nodes=21, scheme="energy-momentum"),
            "hose, water, 40 el.": lambda: scene("liquid", 5e-3, nodes=41, scheme="energy-momentum")}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--rev", help="the earlier commit")
    ap.add_argument("--frames", action="store_true", help="body frames (now) against spatial frames (then), both now")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--cases", default="")
    args = ap.parse_args()
    from varint.schemes.em_tube import TubeEMStep

    if args.frames:
        classes = (("now", TubeEMStep), ("then", lambda m, h: TubeEMStep(m, h, body=False)))
        then = "spatial frames"
    else:
        classes = (("now", TubeEMStep), ("then", module_at(args.rev, "tube_em").TubeEMStep))
        then = f"at {args.rev}"
    print(f"| case | now ms/step | Jac./step | it./step | {then} ms/step | Jac./step | it./step | then / now |")
    print("|---|---|---|---|---|---|---|---|")
    for name, make in cases().items():
        if args.cases and not any(c in name for c in args.cases.split(",")):
            continue
        steppers = {}
        for key, cls in classes:
            s = cls(make(), 5e-3)
            s.step()
            steppers[key] = s
        best = {k: math.inf for k in steppers}
        count = {k: [0, 0, 0] for k in steppers}
        for _ in range(args.rounds):
            for k, s in steppers.items():
                j0, i0 = s.stats["jacobians"], s.stats["iterations"]
                t0 = time.perf_counter()
                for _ in range(args.steps):
                    s.step()
                best[k] = min(best[k], (time.perf_counter() - t0) / args.steps)
                c = count[k]
                c[0] += s.stats["jacobians"] - j0
                c[1] += s.stats["iterations"] - i0
                c[2] += args.steps
        jac = {k: c[0] / c[2] for k, c in count.items()}
        it = {k: c[1] / c[2] for k, c in count.items()}
        print(f"| {name} | {1e3 * best['now']:.1f} | {jac['now']:.2f} | {it['now']:.1f} | {1e3 * best['then']:.1f} | "
              f"{jac['then']:.2f} | {it['then']:.1f} | {best['then'] / best['now']:.2f} |", flush=True)


if __name__ == "__main__":
    main()
