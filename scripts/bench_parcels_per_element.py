"""Cost per step of the garden hose (examples/garden_hose.toml) with one and with two parcels per element, at the same
step (docs/performance.md, "Flowing pipe in time"): what the remedy of docs/theory.md §12 ("Labels passing the
nodes") costs per step.  Each run: 20 steps to warm up, then the best of ``--repeat`` blocks of ``--steps`` steps.

    python scripts/bench_parcels_per_element.py [--steps 200] [--repeat 2]
"""

import argparse
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import varint  # noqa: E402


def per_step(parcels, h, steps, repeat):
    scene = varint.load_scene(ROOT / "examples" / "garden_hose.toml")
    scene.fluid["parcels"] = parcels
    scene.time["step"] = h
    sim = varint.make_simulation(varint.build_model(scene))
    for _ in range(20):
        sim.step()
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(steps):
            sim.step()
        best = min(best, (time.perf_counter() - t0) / steps)
    return best


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--step", type=float, default=5.5e-4)
    a = ap.parse_args(argv)
    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores; h = {a.step:g} s")
    one = per_step(20, a.step, a.steps, a.repeat)
    two = per_step(40, a.step, a.steps, a.repeat)
    print(f"20 parcels (1 per element): {1e3 * one:.1f} ms/step")
    print(f"40 parcels (2 per element): {1e3 * two:.1f} ms/step  (ratio {two / one:.2f})")


if __name__ == "__main__":
    main()
