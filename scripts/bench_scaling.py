"""Cost per step against the number of parcels, Newton iterations against h, and what effects cost.

Prints markdown tables (pasted into docs/performance.md). Timings are wall-clock on this machine;
quote the ratios, not the absolute numbers.  Run:  python scripts/bench_scaling.py
"""

import math
import sys
import time

import numpy as np

from varint import Simulation, build_model
from varint.scene.standard import gas_scene, scene_of

PULSE = lambda L: [{"field": "pressure", "shape": "gaussian", "amplitude": 2e3, "center": 0.5 * L, "width": 0.1 * L}]  # noqa: E731


def time_steps(model, n_min=5, seconds=1.5):
    """Mean wall time per step after the first (compilation, first Jacobian), Newton iterations per step
    and Jacobian factorisations per step over the timed steps."""
    sim = Simulation(model)
    sim.step()  # compile / first Jacobian
    it0, jac0 = sim.stats.total_iterations, sim.stats.total_jacobians
    n, t0 = 0, time.perf_counter()
    while n < n_min or time.perf_counter() - t0 < seconds:
        sim.step()
        n += 1
    dt = (time.perf_counter() - t0) / n
    return dt, (sim.stats.total_iterations - it0) / n, (sim.stats.total_jacobians - jac0) / n


SIZES = (100, 1000, 3000, 10_000, 30_000, 100_000)


def scaling():
    print("\n### Cost per step against the number of parcels (nodes = parcels + 1, h = 0.2 Δs / c)\n")
    print("| parcels | scheme | wall | µs/step | steps/s | Newton it./step | Jacobians/step | µs per parcel-step |")
    print("|---|---|---|---|---|---|---|---|")
    rows = []
    for M in SIZES:
        for scheme, wall in (("midpoint", True), ("trapezoidal", True), ("midpoint", False)):
            h = 0.2 * (1.0 / M) / 340.0
            model = build_model(scene_of(gas_scene(nodes=M + 1, parcels=M, h=h, perturbation=PULSE(1.0), scheme=scheme,
                                                   wall=wall)))
            dt, its, jacs = time_steps(model)
            rows.append((M, scheme, wall, dt))
            print(f"| {M} | {scheme} | {'dynamic' if wall else 'rigid'} | {dt * 1e6:.0f} | {1 / dt:.0f} | {its:.2f} | "
                  f"{jacs:.2f} | {dt * 1e6 / M:.3f} |", flush=True)
    for scheme, wall in (("midpoint", True), ("trapezoidal", True), ("midpoint", False)):
        pts = [(M, dt) for M, s, w, dt in rows if s == scheme and w == wall and M >= 1000]
        slope = np.polyfit(np.log([p[0] for p in pts]), np.log([p[1] for p in pts]), 1)[0]
        steps = "; ".join(f"{b[0]:.0e}->{a[0]:.0e}: {math.log(a[1] / b[1]) / math.log(a[0] / b[0]):.2f}"
                          for b, a in zip(pts[:-1], pts[1:]))
        print(f"\ncost slope d log(time) / d log(parcels), {scheme}, {'dynamic' if wall else 'rigid'} wall, "
              f"10³–10⁵: **{slope:.2f}** (between neighbours: {steps})")


def newton_vs_h():
    print("\n### Newton iterations per step against h (midpoint, 200 parcels, dynamic rubber wall)\n")
    print("| h [s] | c h / Δs | Newton it./step | Jacobians per 100 steps |")
    print("|---|---|---|---|")
    for h in (1e-6, 4e-6, 1.6e-5, 6.4e-5, 2.56e-4):
        model = build_model(scene_of(gas_scene(nodes=201, parcels=200, h=h, perturbation=PULSE(1.0))))
        sim = Simulation(model)
        for _ in range(100):
            sim.step()
        print(f"| {h:.3g} | {340 * h / (1 / 200):.2f} | {sim.stats.total_iterations / 100:.2f} | {sim.stats.total_jacobians} |")


def effects():
    print("\n### What effects cost (2000 parcels, same fluid and h)\n")
    print("| model | unknowns | µs/step | ratio to rigid |")
    print("|---|---|---|---|")
    M = 2000
    h = 0.2 / M / 340.0
    base = None
    for label, kw in (("rigid wall (no R unknowns)", dict(wall=False)), ("dynamic wall", dict(wall=True))):
        model = build_model(scene_of(gas_scene(nodes=M + 1, parcels=M, h=h, perturbation=PULSE(1.0), **kw)))
        dt, _, _ = time_steps(model)
        base = base or dt
        print(f"| {label} | {model.nz} | {dt * 1e6:.0f} | {dt / base:.2f} |")
    d = gas_scene(nodes=M + 1, parcels=M, h=h, perturbation=PULSE(1.0))
    d["wall"] = {"model": "quasistatic", "law": "tube-law", "stiffness": 1e5}
    model = build_model(scene_of(d))
    dt, _, _ = time_steps(model)
    print(f"| quasistatic wall (R algebraic) | {model.nz} | {dt * 1e6:.0f} | {dt / base:.2f} |")


if __name__ == "__main__":
    which = sys.argv[1:] or ["scaling", "newton", "effects"]
    if "scaling" in which:
        scaling()
    if "newton" in which:
        newton_vs_h()
    if "effects" in which:
        effects()
