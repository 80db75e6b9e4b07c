"""The hard cases of docs/theory.md §12 / §9a with the energy-momentum step (docs/theory.md §12a, varint/schemes/em_rod.py).

PyElastica's benchmark section (solid, r = 1 cm, E = 1 MPa), free, released from an arc while spinning.  The
midpoint rod blows up at h = 4-5 ms (and 8 ms for some); the energy-momentum step should run at every step with the
energy to the solver tolerance and the momenta to round-off.  For each case and step: max |E/E0 - 1|, the largest
changes of P (times L, relative to |J0|) and of J (relative to |J0|), the orthonormality defect of the frames,
Newton iterations per step and wall time per step; with --midpoint also the midpoint step's wall time per step on the
same case in 3D (as far as it runs, at most 300 steps).

Run: python scripts/rod_em_hard_cases.py [--steps 2000] [--steps-list 0.004,0.005,0.008] [--midpoint]
     python scripts/rod_em_hard_cases.py --steps 100000 --steps-list 0.005 --cases 0 --every 100   (the 10^5-step run)
     python scripts/rod_em_hard_cases.py --bench 200 --steps-list 0.004   (cost per step against the midpoint)
     python scripts/rod_em_hard_cases.py --constraint   (the inextensible, unshearable rod: rod.constraint)
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from rod_constraint_hard_cases import CASES  # noqa: E402
from rod_stiff_diagnosis import make  # noqa: E402

from varint import Simulation  # noqa: E402
from varint.errors import SolverError  # noqa: E402
from varint.schemes.em_rod import CHI, RodEMStep, strains  # noqa: E402


def run_em(model, h, steps, every=1, progress=0):
    s = RodEMStep(model, h)
    con = 0.0
    E0, P0, J0 = s.energy(), s.linear_momentum(), s.angular_momentum()
    scale = np.linalg.norm(J0)
    worst = dP = dJ = orth = 0.0
    outcome = "runs"
    t0 = time.perf_counter()
    for n in range(steps):
        try:
            s.step()
        except SolverError as exc:
            outcome = f"failed at step {n + 1}: {exc}"[:80]
            break
        if (n + 1) % every == 0 or n + 1 == steps:
            worst = max(worst, abs(s.energy() / E0 - 1))
            dP = max(dP, float(np.max(np.abs(s.linear_momentum() - P0))) * model.rod.L / scale)
            dJ = max(dJ, float(np.max(np.abs(s.angular_momentum() - J0))) / scale)
            orth = max(orth, s.orthonormality())
            if s.constrained:
                con = max(con, float(np.max(np.abs(strains(s.r, s.D, s.ds)[1] - CHI))))
        if progress and (n + 1) % progress == 0:
            print(f"  step {n + 1}: max abs(E/E0-1) {worst:.1e}, dP L/abs(J0) {dP:.1e}, dJ/abs(J0) {dJ:.1e}, "
                  f"{1e3 * (time.perf_counter() - t0) / (n + 1):.1f} ms/step", flush=True)
    wall = time.perf_counter() - t0
    return dict(E=worst, P=dP, J=dJ, orth=orth, con=con, outcome=outcome, wall=wall, steps=s.n,
                its=s.stats["iterations"] / max(s.n, 1), jacs=s.stats["jacobians"] / max(s.n, 1))


def run_midpoint(model, h, steps):
    sim = Simulation(model, h=h)
    t0 = time.perf_counter()
    n = 0
    for n in range(steps):
        try:
            sim.step()
        except SolverError:
            break
    return (time.perf_counter() - t0) / max(n, 1)


def bench(args):
    """ms per step of the energy-momentum and the midpoint step on the same 3D case and step (the first STEPS steps,
    best of three alternating repetitions: the machine is shared)."""
    hs = [float(x) for x in args.steps_list.split(",")]
    names = list(CASES)
    print("| case | h [ms] | energy-momentum ms/step | its/step | midpoint ms/step | its/step | ratio |")
    print("|---|---|---|---|---|---|---|")
    for name in names:
        kw = dict(CASES[name], dim=3)
        if args.constraint:
            kw["constraint"] = "inextensible_unshearable"
        for h in hs:
            te, tm = [], []
            for _ in range(3):
                s = RodEMStep(make(h=h, **kw), h)
                t0 = time.perf_counter()
                for _ in range(args.bench):
                    s.step()
                te.append((time.perf_counter() - t0) / args.bench)
                sim = Simulation(make(h=h, **kw), h=h)
                t0 = time.perf_counter()
                its = 0
                for _ in range(args.bench):
                    sim.step()
                    its += sim.stats.iterations
                tm.append((time.perf_counter() - t0) / args.bench)
            print(f"| {name} | {h * 1e3:g} | {1e3 * min(te):.2f} | {s.stats['iterations'] / args.bench:.1f} | "
                  f"{1e3 * min(tm):.2f} | {its / args.bench:.1f} | {min(te) / min(tm):.0f} |", flush=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--steps-list", default="0.004,0.005,0.008")
    ap.add_argument("--cases", default=None, help="comma-separated case indices (default: all four)")
    ap.add_argument("--every", type=int, default=1, help="monitor every this many steps")
    ap.add_argument("--progress", type=int, default=0, help="print the maxima so far every this many steps")
    ap.add_argument("--midpoint", action="store_true", help="also time the midpoint step (ms per step)")
    ap.add_argument("--constraint", action="store_true",
                    help="the inextensible, unshearable rod (rod.constraint); the table adds max abs(Gamma - chi)")
    ap.add_argument("--bench", type=int, default=0, metavar="STEPS",
                    help="only time STEPS steps of each scheme on each case (3D, same h), interleaved, and print the ratio")
    args = ap.parse_args()
    if args.bench:
        return bench(args)
    hs = [float(x) for x in args.steps_list.split(",")]
    names = list(CASES)
    idx = range(len(names)) if args.cases is None else [int(i) for i in args.cases.split(",")]
    print("| case | h [ms] | steps | max abs(E/E0-1) | max dP L/abs(J0) | max dJ/abs(J0) | frames: max abs(D^T D - I) "
          + ("| max abs(Gamma - chi) " if args.constraint else "")
          + "| Newton its/step | Jacobians/step | ms/step | outcome |" + (" midpoint ms/step |" if args.midpoint else ""))
    print("|---|---|---|---|---|---|---|---|---|---|---|" + ("---|" if args.constraint else "") + ("---|" if args.midpoint else ""))
    for i in idx:
        name, kw = names[i], dict(CASES[names[i]])
        kw["dim"] = 3  # the director step is three-dimensional; the planar cases stay planar
        if args.constraint:
            kw["constraint"] = "inextensible_unshearable"
        for h in hs:
            r = run_em(make(h=h, **kw), h, args.steps, args.every, args.progress)
            con = f" {r['con']:.1e} |" if args.constraint else ""
            line = (f"| {name} | {h * 1e3:.0f} | {r['steps']} | {r['E']:.1e} | {r['P']:.1e} | {r['J']:.1e} | {r['orth']:.1e} |{con}"
                    f" {r['its']:.1f} | {r['jacs']:.2f} | {1e3 * r['wall'] / max(r['steps'], 1):.1f} | {r['outcome']} |")
            if args.midpoint:
                line += f" {1e3 * run_midpoint(make(h=h, **kw), h, min(args.steps, 300)):.2f} |"
            print(line, flush=True)


if __name__ == "__main__":
    main()
