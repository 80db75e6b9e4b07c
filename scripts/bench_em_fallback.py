"""The energy-momentum step where its chord attempt fails: the tumbling rod at steps that leave its stiff modes unresolved.

At h = 10 ms every step of `varint.scene.standard.tumbling_scene` falls back to full Newton
(`varint.schemes.em_rod.em_step`); what the fallback costs is then the step's cost.  Reported per step size: CPU ms per
step (after a warm-up), Jacobians, Newton iterations and fallbacks per step, and the halved steps.  The fallback's
design (the starts' order, giving up a diverging start, chord iterations near the root) is in
`varint/schemes/em_rod.py`; its numbers before and after are in docs/performance.md.

Run:  python scripts/bench_em_fallback.py [--steps 200] [--h 0.005,0.01]
Numbers: docs/performance.md ("The energy-momentum step where its chord attempt fails").
"""

from __future__ import annotations

import argparse
import time

from varint import Simulation, build_model
from varint.scene.standard import tumbling_scene


def measure(h, steps):
    sim = Simulation(build_model(tumbling_scene(h=h)), scheme="energy-momentum")
    for _ in range(5):  # (compilation, the first factorisation)
        sim.step()
    eng = sim.stepper.engine
    s0 = dict(eng.stats)
    t0 = time.process_time()
    for _ in range(steps):
        sim.step()
    cpu = (time.process_time() - t0) / steps
    per = {k: (eng.stats.get(k, 0) - s0.get(k, 0)) / steps for k in ("jacobians", "iterations", "fallbacks")}
    return cpu, per, eng.stats.get("halvings", 0) - s0.get("halvings", 0)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--h", default="0.005,0.01", help="comma-separated step sizes [s]")
    a = ap.parse_args()
    print("| h [ms] | CPU ms/step | Jacobians/step | Newton it./step | fallbacks/step | halved steps |\n|---|---|---|---|---|---|")
    for h in (float(x) for x in a.h.split(",")):
        cpu, per, halved = measure(h, a.steps)
        print(f"| {1e3 * h:g} | {1e3 * cpu:.1f} | {per['jacobians']:.2f} | {per['iterations']:.1f} | {per['fallbacks']:.2f} | "
              f"{halved} |", flush=True)


if __name__ == "__main__":
    main()
