"""Cold start: what the first step of an example compiles, and for how long (an empty numba cache).

Runs in a fresh process with NUMBA_CACHE_DIR set to an empty temporary folder (so nothing is loaded from the
project's cache), builds the example's Simulation and takes one step, recording numba's compile events: the wall time
of the whole, and the kernels whose compilation took longest (inclusive of the kernels they compile in turn).

Run:  python scripts/bench_cold_start.py [examples/tumbling_rod.toml] [--top 10]
Numbers: docs/performance.md ("Cold start of the compiled rod step").
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

#: the measured process: one step of the scene, numba's compile events summed per kernel
PROBE = r'''
import json, sys, time
t0 = time.perf_counter()
from numba.core import event
with event.install_recorder("numba:compile") as rec:
    from varint import Simulation, build_model, load_scene
    Simulation(build_model(load_scene(sys.argv[1]))).step()
total = time.perf_counter() - t0
open_, spent = {}, {}
for ts, ev in rec.buffer:
    name = ev.data["dispatcher"].py_func.__qualname__ if ev.data and "dispatcher" in ev.data else str(ev.data)
    if ev.is_start:
        open_[name] = ts
    elif name in open_:
        spent[name] = spent.get(name, 0.0) + ts - open_.pop(name)
print(json.dumps({"total": total, "kernels": spent}))
'''


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene", nargs="?", default=str(ROOT / "examples" / "tumbling_rod.toml"))
    ap.add_argument("--top", type=int, default=10)
    a = ap.parse_args()
    import json

    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache, PYTHONPATH=str(ROOT), OPENBLAS_NUM_THREADS="1")
        out = subprocess.run([sys.executable, "-c", PROBE, a.scene], env=env, capture_output=True, text=True, check=True)
    r = json.loads(out.stdout.strip().splitlines()[-1])
    print(f"{Path(a.scene).name}: first step with an empty numba cache {r['total']:.1f} s")
    print("| kernel | compile s (inclusive) |\n|---|---|")
    for name, s in sorted(r["kernels"].items(), key=lambda kv: -kv[1])[:a.top]:
        print(f"| {name} | {s:.2f} |")


if __name__ == "__main__":
    main()
