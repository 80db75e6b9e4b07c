"""One rod step against one PyElastica step at 10-400 elements, before and after the compiled rod step.

Case: PyElastica's benchmark cantilever (scripts/bench_pyelastica.py: L = 1 m, solid radius 1 cm, rho = 1000 kg/m^3,
E = 1e6 Pa, G = E/1.5), planar, released from the first mode shape.  varint at h = T1/64 (64 steps per first period):
"before" is the general stepper path (Step + varint.schemes.newton, which Simulation used for rod-only scenes before the
compiled step), "after" the compiled rod step (varint/schemes/rod_compiled.py FastRodStep, which Simulation takes now).
PyElastica: PositionVerlet at half its largest stable step at each resolution (found by bisection on 3000-step runs;
the cost per step does not depend on the step).  The three are timed in alternating blocks (PyElastica 2000 steps,
varint 50-200 steps), the cheapest block of ROUNDS each: the three see the same machine load, so the ratios are
fair even on a shared machine.

PyElastica is an optional comparison tool, not a dependency:  pip install -e '.[compare]'
Run:  python scripts/bench_rod_step_vs_pyelastica.py [--elements 10,25,50,100,200,400] [--rounds 5] [--quick]
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_pyelastica import largest_stable_dt, pyelastica_stepper, reference  # noqa: E402
from bench_rod_step_fast import cantilever  # noqa: E402

from varint import Simulation  # noqa: E402
from varint.schemes.rod_compiled import FastRodStep  # noqa: E402

E = 1e6


def timed(fn, n):
    t0 = time.perf_counter()
    fn(n)
    return (time.perf_counter() - t0) / n


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--elements", default="10,25,50,100,200,400")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--quick", action="store_true", help="10 and 50 elements, 2 rounds, short blocks")
    args = ap.parse_args()
    try:
        import elastica  # noqa: F401
    except ImportError:
        print("PyElastica not installed: pip install -e '.[compare]'")
        return 1
    sizes = [10, 50] if args.quick else [int(x) for x in args.elements.split(",")]
    rounds = 2 if args.quick else args.rounds
    w1 = reference(E)
    h = 2 * math.pi / w1 / 64
    print(f"# varint h = T1/64 = {h:.4g} s; PyElastica at half its largest stable step; cheapest of {rounds} "
          "alternating blocks\n")
    print("| elements | PyElastica dt [s] | PyElastica µs/step | varint before (stepper) µs/step | ratio before | "
          "varint after (compiled) µs/step | ratio after | after: it./step |")
    print("|---|---|---|---|---|---|---|---|")
    for n_el in sizes:
        dt = 0.5 * largest_stable_dt(E, w1, n_el=n_el, steps=300 if args.quick else 3000)
        pe = pyelastica_stepper(E, dt, n_el)
        old = Simulation(cantilever(n_el, h, 2))
        old.stepper.compiled = None  # the general path
        old.step()
        fast = FastRodStep(cantilever(n_el, h, 2))
        state = [fast.step(Simulation(fast.model).state)]
        its = [0, 0]

        def run_old(n):
            for _ in range(n):
                old.step()

        def run_fast(n):
            for _ in range(n):
                state[0] = fast.step(state[0])
                its[0] += fast.last["iterations"]
                its[1] += 1

        m = max(20, min(200, 20000 // n_el)) // (4 if args.quick else 1)
        best = [math.inf] * 3
        for _ in range(rounds):
            best[0] = min(best[0], timed(pe, 500 if args.quick else 2000))
            best[1] = min(best[1], timed(run_old, m))
            best[2] = min(best[2], timed(run_fast, m))
        t_pe, t_old, t_fast = best
        print(f"| {n_el} | {dt:.3g} | {t_pe * 1e6:.4g} | {t_old * 1e6:.4g} | {t_old / t_pe:.1f} | {t_fast * 1e6:.4g} | "
              f"{t_fast / t_pe:.1f} | {its[0] / its[1]:.2f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
