"""What a step costs on the one model, optionally interleaved against another checkout of varint.

Cases: `examples/tumbling_rod.toml` (a free rod, 200 steps) and `examples/rubber_tube_pulse.toml` (the
paper's rubber tube, 50 steps): best of 3 repeats after a warm-up, ms per step and Newton iterations per
step.  With ``--ref PATH`` (e.g. a `git worktree` of an older commit) the same cases run in that tree too,
alternating with this one, each in its own process, and the ratios are printed (docs/performance.md,
"What the one model costs").

Run:  python scripts/bench_one_model.py [--ref PATH] [--rounds 2]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

CHILD = r"""
import json, sys, time
from pathlib import Path
import varint
out = {}
for name, steps in (("tumbling_rod", 200), ("rubber_tube_pulse", 50)):
    scene = varint.parse_scene((Path(sys.argv[1]) / "examples" / f"{name}.toml").read_text())
    model = varint.build_model(scene)
    sim = varint.make_simulation(model)
    for _ in range(10):
        sim.step()
    best = 1e9
    for _ in range(3):
        t = time.perf_counter()
        for _ in range(steps):
            sim.step()
        best = min(best, (time.perf_counter() - t) / steps)
    out[name] = {"ms_per_step": 1e3 * best, "iterations_per_step": sim.stats.total_iterations / sim.state.n}
print(json.dumps(out))
"""


def measure(tree):
    env = dict(os.environ, PYTHONPATH=str(tree))
    # (run in the tree itself: "python -c" puts the working directory first on sys.path)
    proc = subprocess.run([sys.executable, "-c", CHILD, str(ROOT)], capture_output=True, text=True, env=env, check=True,
                          cwd=str(tree))
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--ref", help="another varint checkout to compare with (its package is imported from there)")
    ap.add_argument("--rounds", type=int, default=2, help="alternating rounds; the best of each is kept")
    args = ap.parse_args()
    trees = {"this": ROOT} | ({"ref": Path(args.ref).resolve()} if args.ref else {})
    best = {k: {} for k in trees}
    for _ in range(args.rounds):
        for label, tree in trees.items():
            for case, r in measure(tree).items():
                old = best[label].get(case)
                if old is None or r["ms_per_step"] < old["ms_per_step"]:
                    best[label][case] = r
    print("| case | " + " | ".join(f"{k} (ms/step, it/step)" for k in trees) + (" | this / ref |" if args.ref else " |"))
    print("|---" * (len(trees) + 1 + bool(args.ref)) + "|")
    for case in best["this"]:
        cells = [f"{best[k][case]['ms_per_step']:.3f}, {best[k][case]['iterations_per_step']:.2f}" for k in trees]
        ratio = f" | {best['this'][case]['ms_per_step'] / best['ref'][case]['ms_per_step']:.2f} |" if args.ref else " |"
        print(f"| {case} | " + " | ".join(cells) + ratio)


if __name__ == "__main__":
    main()
