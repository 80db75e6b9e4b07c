"""A rod step's cost now against the same step at an earlier commit, in alternating blocks of one process.

The earlier version of the step's module is read from git (``git show REV:varint/<module>.py``) and loaded beside the
current package (its relative imports pointed at ``varint``), so both run on the same machine load: the ratio is fair
on a shared machine, the absolute times are not.

  --which em    varint/schemes/em_rod.py (RodEMStep): the hard cases of docs/theory.md §12 (scripts/rod_constraint_hard_cases.py
                CASES; 3D, N = 50) at 5 ms, 150 steps per block
  --which fast  varint/schemes/rod_compiled.py (FastRodStep): PyElastica's cantilever (scripts/bench_rod_step_fast.py) at
                64 steps per first period, 100 and 1000 elements, planar and 3D

Run:  python scripts/bench_rod_step_vs_commit.py --which em --rev fed81a8     (before session 7's EM speed-ups)
      python scripts/bench_rod_step_vs_commit.py --which fast --rev 0617cf6   (before the midpoint's momentum fix)
"""

from __future__ import annotations

import argparse
import importlib.util
import math
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "scripts"))

from varint import Simulation  # noqa: E402


def module_at(rev, name):
    """The module ``name`` (e.g. "schemes/em_rod") at git revision rev, loaded as a standalone module; a revision
    from before the package's layers (fb7a82d) has it flat (varint/rod_em.py, varint/rod_step_fast.py), and its
    relative imports are pointed at the current package's modules of the same name."""
    flat = {"schemes/em_rod": "rod_em", "schemes/rod_compiled": "rod_step_fast"}[name]
    show = subprocess.run(["git", "show", f"{rev}:varint/{name}.py"], cwd=ROOT, capture_output=True, text=True)
    if show.returncode == 0:
        text, pkg = show.stdout, "varint." + name.rsplit("/", 1)[0]
        text = re.sub(r"from \.\.(\w[\w.]*) import", r"from varint.\1 import", text)
        text = re.sub(r"from \.(\w[\w.]*) import", rf"from {pkg}.\1 import", text)
        text = re.sub(r"from \. import", rf"from {pkg} import", text)
    else:  # before the layers: flat modules whose names moved (the current package has them in its layers)
        text = subprocess.run(["git", "show", f"{rev}:varint/{flat}.py"], cwd=ROOT, check=True, capture_output=True,
                              text=True).stdout
        moved = {"rod": "terms.rod", "errors": "errors", "newton": "schemes.newton", "lie": "lattice.lie",
                 "stepper": "schemes.state"}
        text = re.sub(r"from \.(\w+) import", lambda m: f"from varint.{moved.get(m.group(1), m.group(1))} import", text)
        text = text.replace("from varint.schemes.state import Step", "from varint.schemes.midpoint import Step")
        text = re.sub(r"\b_k_(body_rows|cay|chart_column|element|measure)\b", r"k_\1", text)
    path = Path(tempfile.mkdtemp()) / f"{flat}_at_{rev}.py"
    path.write_text(text)
    spec = importlib.util.spec_from_file_location(path.stem, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def alternate(blocks, steps, rounds):
    """Cheapest time per step of each named stepping function over alternating blocks."""
    best = {k: math.inf for k in blocks}
    for _ in range(rounds):
        for k, run in blocks.items():
            t0 = time.perf_counter()
            run(steps)
            best[k] = min(best[k], (time.perf_counter() - t0) / steps)
    return best


def bench_em(rev, rounds):
    from rod_constraint_hard_cases import CASES
    from rod_stiff_diagnosis import make

    from varint.schemes.em_rod import RodEMStep

    old = module_at(rev, "schemes/em_rod")
    print("| case | now ms/step | at " + rev + " ms/step | ratio |\n|---|---|---|---|")
    for name, kw in CASES.items():
        kw = dict(kw, dim=3)
        blocks = {}
        for key, cls in (("now", RodEMStep), ("then", old.RodEMStep)):
            s = cls(make(h=5e-3, **kw), 5e-3)
            for _ in range(5):
                s.step()
            blocks[key] = (lambda s: lambda n: [s.step() for _ in range(n)])(s)
        b = alternate(blocks, 150, rounds)
        print(f"| {name} | {1e3 * b['now']:.2f} | {1e3 * b['then']:.2f} | {b['then'] / b['now']:.2f} |", flush=True)


def bench_fast(rev, rounds):
    from bench_pyelastica import reference
    from bench_rod_step_fast import E, cantilever

    from varint.schemes.rod_compiled import FastRodStep

    old = module_at(rev, "schemes/rod_compiled")
    T1 = 2 * math.pi / reference(E)
    print("| model | elements | now µs/step | it./step | at " + rev + " µs/step | it./step | now / then |")
    print("|---|---|---|---|---|---|---|")
    for N, dim in ((100, 2), (100, 3), (1000, 2)):
        blocks, its = {}, {}
        for key, cls in (("now", FastRodStep), ("then", old.FastRodStep)):
            f = cls(cantilever(N, T1 / 64, dim))
            st = [f.step(Simulation(f.model).state)]
            its[key] = [0, 0]

            def run(n, f=f, st=st, c=its[key]):
                for _ in range(n):
                    st[0] = f.step(st[0])
                    c[0] += f.last["iterations"]
                    c[1] += 1

            blocks[key] = run
        b = alternate(blocks, 200 if N == 100 else 30, rounds)
        it = {k: v[0] / v[1] for k, v in its.items()}
        print(f"| {'planar' if dim == 2 else '3D'} | {N} | {1e6 * b['now']:.1f} | {it['now']:.2f} | {1e6 * b['then']:.1f} | "
              f"{it['then']:.2f} | {b['now'] / b['then']:.3f} |", flush=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--which", choices=("em", "fast"), required=True)
    ap.add_argument("--rev", required=True, help="the earlier commit")
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args()
    (bench_em if args.which == "em" else bench_fast)(args.rev, args.rounds)


if __name__ == "__main__":
    main()
