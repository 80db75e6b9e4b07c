"""Cost of the modal analysis (dense vs shift-invert sparse) and of one rod derivative call.

Prints the tables recorded in docs/performance.md, all measured in this one run:
* rod_modes on a 3D clamped-free cantilever (the PyElastica section) at growing size, dense and
  sparse, the lowest 6 modes, with the first frequency against Timoshenko;
* tube modes (closed dynamic-wall gas tube) at growing size, dense and sparse;
* one complex-step derivative call of the rod (D1 L_d, the reference path `derivative_complex_step`), 11 and 101 nodes, 3D.
Run:  python scripts/bench_modes.py
"""

import time

import numpy as np

from varint import build_model
from varint.analysis.linear import modes
from varint.analysis.rod_modes import rod_modes
from varint.exact.beams import timoshenko_cantilever
from varint.scene.standard import gas_scene, rod_scene, scene_of, solid_section


def best_of(fn, repeat=3):
    out, best = None, np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def rod_table():
    sec = solid_section()
    w1 = timoshenko_cantilever(sec["bending_stiffness"], sec["shear_stiffness"], sec["mass_per_length"],
                               sec["rotary_inertia"], 1.0, count=1)[0]
    print("| rod elements | unknowns | dense s | sparse s | dense / sparse | 1st frequency error (sparse) |\n|---|---|---|---|---|---|")
    for n in (50, 100, 200, 1000):
        model = build_model(rod_scene(nodes=n + 1, section=sec, ends=("clamped", "free")))
        ts, fs = best_of(lambda: rod_modes(model, count=6, method="sparse"))
        td = best_of(lambda: rod_modes(model, count=6, method="dense"), 1)[0] if model.nz <= 1500 else float("nan")
        ratio = f"{td / ts:.0f}" if np.isfinite(td) else "(dense not run)"
        print(f"| {n} | {model.nz} | {td:.3g} | {ts:.3g} | {ratio} | {fs[0]['frequency'] / w1 - 1:+.1e} |", flush=True)


def tube_table():
    print("\n| tube parcels | inertial unknowns | dense s | sparse s | dense / sparse |\n|---|---|---|---|---|")
    for parcels in (250, 1000, 2000):
        model = build_model(scene_of(gas_scene(nodes=parcels + 1, parcels=parcels)))
        ts = best_of(lambda: modes(model, count=6, method="sparse"))[0]
        td = best_of(lambda: modes(model, count=6, method="dense"), 1)[0]
        print(f"| {parcels} | {model.tube.nq} | {td:.3g} | {ts:.3g} | {td / ts:.0f} |", flush=True)


def derivative_table():
    print("\n| rod nodes (3D) | one derivative call, us |\n|---|---|")
    for nodes in (11, 101):
        rod = build_model(rod_scene(nodes=nodes)).rod
        Lam, r = rod.Lam0, rod.r0
        xi, r1 = np.full((nodes, 3), 0.01), r + 1e-3
        rod.derivative_complex_step(1e-3, Lam, r, xi, r1, 0)  # compile / warm the kernel
        t = best_of(lambda: [rod.derivative_complex_step(1e-3, Lam, r, xi, r1, 0) for _ in range(300)], 5)[0]
        print(f"| {nodes} | {t / 300 * 1e6:.0f} |", flush=True)


if __name__ == "__main__":
    rod_table()
    tube_table()
    derivative_table()
