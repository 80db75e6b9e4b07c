"""What a [fluid] costs that does nothing: a rod alone against the same rod carrying a gas of negligible density.

The issue "one engine" asks that a rod with a [fluid] of density 1e-6 cost at most twice the rod alone per step.
The rod alone steps through the compiled backend (varint/schemes/rod_compiled.py, one numba call per step); with a
fluid the model is the coupled tube, stepped by the general variational step (Python terms, scipy's sparse LU).
Both in one process, interleaved blocks, CPU time per step (min over blocks), Newton iterations per step.

Run:  python scripts/bench_negligible_fluid.py [--elements 100] [--steps 20] [--rounds 5]
Numbers: docs/performance.md ("A fluid that does nothing").
"""

from __future__ import annotations

import argparse
import time

from varint import Simulation, build_model, parse_scene
from varint.scene.text import to_toml


def scene(n, fluid, h=1e-3):
    rod = dict(mass_per_length=1.0, rotary_inertia=0.01, bending_stiffness=1.0, torsional_stiffness=0.8,
               axial_stiffness=1e3, shear_stiffness=1e3, dimension=3, ends={"s0": "clamped", "sL": "free"})
    rod["perturbation"] = [{"field": "velocity", "shape": "cosine", "amplitude": 0.1, "wavelength": 2.0}]
    d = {"title": "rod", "tube": {"length": 1.0, "nodes": n + 1, "radius": 0.01}, "rod": rod,
         "time": {"step": h, "end": 1.0}}
    if fluid:
        d["fluid"] = {"model": "ideal-gas", "density": 1e-6, "pressure": 1e-2, "parcels": n}
        d["environment"] = {"external_pressure": 1e-2}
    return build_model(parse_scene(to_toml(d)))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--elements", default="100")
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args()
    print("| elements | rod alone ms/step | it./step | rod + negligible gas ms/step | it./step | ratio |")
    print("|---|---|---|---|---|---|")
    for n in map(int, args.elements.split(",")):
        sims = {k: Simulation(scene(n, k == "fluid")) for k in ("rod", "fluid")}
        for s in sims.values():
            for _ in range(3):
                s.step()
        best, its = {k: float("inf") for k in sims}, {}
        for _ in range(args.rounds):
            for k, s in sims.items():
                it0 = s.stats.total_iterations
                t0 = time.process_time()
                for _ in range(args.steps):
                    s.step()
                best[k] = min(best[k], (time.process_time() - t0) / args.steps)
                its[k] = (s.stats.total_iterations - it0) / args.steps
        print(f"| {n} | {1e3 * best['rod']:.3f} | {its['rod']:.2f} | {1e3 * best['fluid']:.3f} | {its['fluid']:.2f} | "
              f"{best['fluid'] / best['rod']:.1f} |", flush=True)


if __name__ == "__main__":
    main()
