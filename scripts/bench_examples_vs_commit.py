"""Every example scene's cost per step now against an earlier commit, interleaved, CPU time.

The earlier commit is checked out into a temporary git worktree; one worker process per tree (each with its own
package and numba cache, one BLAS thread) builds every example's Simulation and warms it up (compilation, the first
Jacobians); then the workers step the examples in alternating blocks of ``--steps`` steps, so both trees see the same
machine load, and each block's CPU time (``time.process_time`` in the worker) is recorded.  Both trees step the
earlier commit's example files (the same scenes).  The table gives the cheapest block per step of each tree and their ratio (now / then; > 1: slower now), and the median of the rounds'
ratios (each round times both trees back to back: robust to the machine's drift).  Pass ``--rev`` the commit to
compare with (default: cba3494, the last commit before the package was laid out in layers and the schemes became
registered objects).

Run:  python scripts/bench_examples_vs_commit.py [--rev REV] [--steps 20] [--rounds 5] [--examples a,b]
Numbers: docs/performance.md ("Every example against the layout's parent commit").
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent

#: the worker: reads "build NAME", "block NAME STEPS" and "quit" lines, answers one JSON line each
WORKER = r'''
import json, sys, time
import varint
sims = {}
for line in sys.stdin:
    cmd = line.split()
    if cmd[0] == "quit":
        break
    if cmd[0] == "build":
        name, path, warm = cmd[1], cmd[2], int(cmd[3])
        scene = varint.load_scene(path)
        sim = varint.Simulation(varint.build_model(scene))
        for _ in range(warm):
            sim.step()
        sims[name] = sim
        print(json.dumps({"ok": True, "h": sim.h}), flush=True)
    elif cmd[0] == "block":
        sim, steps = sims[cmd[1]], int(cmd[2])
        t0 = time.process_time()
        for _ in range(steps):
            sim.step()
        print(json.dumps({"cpu": (time.process_time() - t0) / steps}), flush=True)
'''


def worker(tree):
    env = dict(os.environ, PYTHONPATH=str(tree), OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    return subprocess.Popen([sys.executable, "-c", WORKER], cwd=tree, env=env, stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True)


def ask(proc, line):
    proc.stdin.write(line + "\n")
    proc.stdin.flush()
    out = proc.stdout.readline()
    if not out:
        raise RuntimeError(f"worker died on {line!r}")
    return json.loads(out)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rev", default="cba3494", help="the earlier commit (default: %(default)s)")
    ap.add_argument("--steps", type=int, default=20, help="steps per block (default: %(default)s)")
    ap.add_argument("--rounds", type=int, default=5, help="blocks per tree and example (default: %(default)s)")
    ap.add_argument("--warm", type=int, default=3, help="steps before timing (default: %(default)s)")
    ap.add_argument("--examples", default="", help="comma-separated example names (default: all)")
    args = ap.parse_args()
    old = Path(tempfile.mkdtemp(prefix="varint_then_")) / "tree"
    subprocess.run(["git", "worktree", "add", "--detach", str(old), args.rev], cwd=ROOT, check=True,
                   capture_output=True)
    # both trees step the earlier commit's example files, so that the same scene is timed (an example whose file
    # changed since, e.g. a scheme chosen in it, would otherwise compare two different runs)
    names = [p.stem for p in sorted((old / "examples").glob("*.toml"))]
    if args.examples:
        names = [n for n in names if n in args.examples.split(",")]
    procs = {"now": worker(ROOT), "then": worker(old)}
    try:
        print(f"| example | h (s) | now ms/step | at {args.rev} ms/step | now / then (best blocks) | median of the "
              f"rounds' ratios |\n|---|---|---|---|---|---|", flush=True)
        for name in names:
            path = old / "examples" / f"{name}.toml"
            h = {k: ask(p, f"build {name} {path} {args.warm}")["h"] for k, p in procs.items()}
            best = {k: float("inf") for k in procs}
            ratios = []
            for _ in range(args.rounds):
                pair = {k: ask(p, f"block {name} {args.steps}")["cpu"] for k, p in procs.items()}
                ratios.append(pair["now"] / pair["then"])
                for k in procs:
                    best[k] = min(best[k], pair[k])
            print(f"| {name} | {h['now']:.3g} | {1e3 * best['now']:.3f} | {1e3 * best['then']:.3f} | "
                  f"{best['now'] / best['then']:.3f} | {float(np.median(ratios)):.3f} |", flush=True)
    finally:
        for p in procs.values():
            try:
                ask(p, "quit")
            except (RuntimeError, BrokenPipeError, json.JSONDecodeError):
                pass
            p.kill()
        subprocess.run(["git", "worktree", "remove", "--force", str(old)], cwd=ROOT, capture_output=True)


if __name__ == "__main__":
    main()
