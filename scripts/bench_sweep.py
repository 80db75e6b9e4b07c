"""Wall time of one ``varint sweep`` on a local Dask cluster of 1 and of 2 workers (docs/performance.md).

The sweep: the cantilevered pipe conveying fluid of docs/validation.md (L = 1, EI = 1, beta = 0.2, planar,
``--nodes`` nodes, a velocity inlet and a free jet) over ``--points`` flow velocities, ``--analysis modes``; the
same sweep is run into two fresh directories, first with 1 worker then with 2 (then, with ``--repeat 2``, once
more each, interleaved), and the two tables must be identical to the last digit.  The cluster's start-up is
inside the measured time (it is what a user waits for); it is also reported on its own (an empty sweep cannot
be timed, so: a 1-point sweep).  Run it with nothing else running:

    python scripts/bench_sweep.py [--points 64] [--nodes 41] [--repeat 1]
"""

import argparse
import filecmp
import os
import subprocess
import sys
import tempfile
import time

from varint.scene.standard import pipe_scene_text

HERE = os.path.dirname(os.path.abspath(__file__))


def run_sweep(scene, out, points, workers):
    cmd = [sys.executable, "-m", "varint", "sweep", scene, "--vary", f"fluid.velocity=5:25:{points}",
           "--analysis", "modes", "-n", "8", "--out", out, "--workers", str(workers)]
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=int, default=64)
    ap.add_argument("--nodes", type=int, default=41)
    ap.add_argument("--repeat", type=int, default=1)
    a = ap.parse_args()
    import math

    with tempfile.TemporaryDirectory() as tmp:
        scene = os.path.join(tmp, "pipe.toml")
        with open(scene, "w") as f:
            # the cantilevered pipe at beta = 0.2 with the inflow at 5 m/s (u = 5 sqrt(0.2))
            f.write(pipe_scene_text(("clamped", "free"), 0.2, 5.0 * math.sqrt(0.2), a.nodes, 2))
        start = {w: run_sweep(scene, os.path.join(tmp, f"start{w}"), 1, w) for w in (1, 2)}
        times = {1: [], 2: []}
        for r in range(a.repeat):
            for w in (1, 2):
                times[w].append(run_sweep(scene, os.path.join(tmp, f"w{w}_{r}"), a.points, w))
        same = all(filecmp.cmp(os.path.join(tmp, f"w1_{r}", "sweep.csv"), os.path.join(tmp, f"w2_{r}", "sweep.csv"),
                               shallow=False) for r in range(a.repeat))
    print(f"modes sweep of {a.points} points, cantilevered pipe, {a.nodes} nodes (planar)")
    print(f"{'workers':>8} {'wall time (s)':>14} {'per point (s)':>14} {'1-point sweep (s)':>18}")
    for w in (1, 2):
        best = min(times[w])
        print(f"{w:>8} {best:>14.2f} {best / a.points:>14.3f} {start[w]:>18.2f}")
    print(f"speed-up 2 vs 1 workers: {min(times[1]) / min(times[2]):.2f}x; tables identical: {same}")


if __name__ == "__main__":
    main()
