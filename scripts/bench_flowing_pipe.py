"""Cost of the flowing pipe in time (open ends on the coupled tube, docs/theory.md §13) and of finding its threshold.

1. Cost per step against the lattice: Païdoussis' cantilever (beta = 0.2, u = 2, below its threshold; EI = 1, L = 1,
   M + m = 1; the inextensible rod, planar), 10 ... 160 elements with as many parcels, the step set so the inlet moves
   0.4 of a parcel per step (the lattice changes every 2.5 steps: the step, its Newton factor and the kinetic metric
   are rebuilt then).  The cheapest of ``--repeat`` blocks of ``--steps`` steps after a warm-up.
2. A threshold two ways: varint.analysis.thresholds.threshold (bisection on the sign of the largest growth rate of the
   linearisation) against finding it by runs (one kicked run of 1.45 s per bisection point, its growth rate fitted from
   the tip's peaks; the run's cost is measured once and multiplied by the bisection count of the same tolerance).

    python scripts/bench_flowing_pipe.py [--steps 40] [--repeat 3] [--sizes 10 20 40 80 160]

Numbers: docs/performance.md ("Flowing pipe in time").
"""

import argparse
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from varint.analysis.thresholds import threshold  # noqa: E402
from varint.model.model import build_model  # noqa: E402
from varint.scene.standard import pipe_scene_text  # noqa: E402
from varint.scene.schema import parse_scene  # noqa: E402
from varint.run.simulation import Simulation  # noqa: E402

BETA = 0.2


def pipe(ends, u, nodes, h, kick):
    """The inextensible pipe of the tests (tests/test_coupled_open_ends.py) at beta = BETA."""
    return parse_scene(pipe_scene_text(ends, BETA, u, nodes, 2, constraint="inextensible_unshearable", h=h, kick=kick))


def run(scene, T):
    sim = Simulation(build_model(scene))
    for _ in range(int(round(T / sim.h))):
        sim.step()
    return sim


def per_step(elements, steps, repeat, u=2.0):
    U = u / math.sqrt(BETA)
    h = 0.4 / (elements * U)
    sim = Simulation(build_model(pipe(("clamped", "free"), u, elements + 1, h=h, kick=1e-3)))
    for _ in range(5):
        sim.step()
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(steps):
            sim.step()
        best = min(best, (time.perf_counter() - t0) / steps)
    return best, h


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=40)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--sizes", type=int, nargs="+", default=[10, 20, 40, 80, 160])
    a = ap.parse_args(argv)
    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    print("elements  step h [s]  ms/step  us/step/element")
    for n in a.sizes:
        c, h = per_step(n, a.steps, a.repeat)
        print(f"{n:8d}  {h:9.3g}  {1e3 * c:7.2f}  {1e6 * c / n:8.1f}")
    # the threshold: modes route
    t0 = time.perf_counter()
    res = threshold(pipe_scene_text(("clamped", "free"), BETA, 1.0, 21, 2), 5.0 / math.sqrt(BETA), 6.2 / math.sqrt(BETA),
                    count=8, rtol=1e-3)
    t_modes = time.perf_counter() - t0
    u_modes = res["value"] * math.sqrt(BETA)
    n_bisect = int(math.ceil(math.log2((6.2 - 5.0) / (1e-3 * u_modes))))
    # one run of the time-domain route (20 elements, 1.45 s, h = 1.8e-3) at 1.07 u_cr
    t0 = time.perf_counter()
    run(pipe(("clamped", "free"), 1.07 * 5.591405782948218, 21, h=1.8e-3, kick=1e-3), 1.45)
    t_run = time.perf_counter() - t0
    print(f"threshold by modes (20 elements, rtol 1e-3): u_cr = {u_modes:.4f} in {t_modes:.2f} s")
    print(f"one run (20 elements, 1.45 s simulated, 806 steps): {t_run:.1f} s; by runs, {n_bisect} bisection points: "
          f"{n_bisect * t_run:.0f} s ({n_bisect * t_run / t_modes:.0f} x the modes route)")


if __name__ == "__main__":
    main()
