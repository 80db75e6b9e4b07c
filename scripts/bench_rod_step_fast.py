"""The compiled rod step (varint/schemes/rod_compiled.py) against the stepper (Simulation.step) and PyElastica's step.

Case: PyElastica's benchmark cantilever (scripts/bench_pyelastica.py: L = 1 m, solid radius 1 cm, rho = 1000 kg/m^3,
E = 1e6 Pa, G = E/1.5), released from the first Euler-Bernoulli mode shape with a 1 cm tip deflection, at the step
of 64 steps per first period (h = T1/64, the step that gives a 5 % tip error over 10 periods at 100 elements:
docs/performance.md "The rod against PyElastica").  Planar (3 unknowns per node) and 3D (6 per node) models at
10 to 10^5 elements; both paths run the same number of steps from the same state, and their states are compared.

Reported per size: microseconds per step of each path, Newton iterations and Jacobians per step, the ratio, and the
largest relative difference of the two paths' level vectors; the slope of log(cost) against log(nodes) from 10^2 to
10^5; the fast step's cost at 100 elements against the steps per period (the Newton iterations a step needs follow
the motion per step); PyElastica's PositionVerlet step on the same rod at 100 elements (if installed:
pip install -e '.[compare]').

Run:  python scripts/bench_rod_step_fast.py [--quick]
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent
sys.path.insert(0, str(ROOT))

import bench_pyelastica  # noqa: E402
from bench_pyelastica import L, N_EL, RAD, RHO, mode_shape, reference  # noqa: E402
from varint.scene.standard import solid_section  # noqa: E402
from varint.scene.text import to_toml  # noqa: E402

from varint import Simulation, build_model, parse_scene  # noqa: E402
from varint.lattice.lie import cay  # noqa: E402
from varint.schemes.rod_compiled import FastRodStep  # noqa: E402

E = 1e6


def cantilever(N, h, dim):
    sec = solid_section(E, RAD, RHO)
    d = {"title": "cantilever", "tube": {"length": L, "nodes": N + 1, "radius": RAD},
         "rod": dict(sec, dimension=dim, measure="reference", ends={"s0": "clamped", "sL": "free"}),
         "time": {"step": h, "end": 1.0}}
    model = build_model(parse_scene(to_toml(d)))
    s = np.linspace(0.0, L, N + 1)
    y, dy = mode_shape(s)
    model.rod.set_configuration(cay(np.stack([0 * s, 0 * s, 2 * np.tan(0.5 * np.arctan(dy))], axis=1)),
                                np.stack([s, y, 0 * s], axis=1))
    return model


def steps_for(N, budget):
    return int(max(3, min(400, budget / N)))


def _blocks(n):
    """n steps timed in up to 4 blocks; a path's cost is its cheapest block (the machine is shared: the minimum is
    the estimate least disturbed by other processes)."""
    k = min(4, n)
    return [n // k + (1 if i < n % k else 0) for i in range(k)]


def run_old(model, n):
    sim = Simulation(model)
    sim.stepper.compiled = None  # the general path (Step + varint.schemes.newton), which Simulation used for the rod before the hook
    sim.step()  # compiled kernels, first Jacobian
    its = jacs = 0
    best = math.inf
    for m in _blocks(n):
        t0 = time.perf_counter()
        for _ in range(m):
            sim.step()
            its += sim.stats.iterations
            jacs += sim.stats.n_jacobian
        best = min(best, (time.perf_counter() - t0) / m)
    return best, its / n, jacs / n, sim.state


def run_fast(model, n, fast=None, st=None):
    fast = fast or FastRodStep(model)
    st = st or fast.step(Simulation(model).state)
    its = jacs = 0
    best = math.inf
    for m in _blocks(n):
        t0 = time.perf_counter()
        for _ in range(m):
            st = fast.step(st)
            its += fast.last["iterations"]
            jacs += fast.last["n_jacobian"]
        best = min(best, (time.perf_counter() - t0) / m)
    return best, its / n, jacs / n, st, fast.fallbacks


def pyelastica_stepper():
    """PositionVerlet on the same rod at 100 elements, at half its stability limit (scripts/bench_pyelastica.py):
    (a function doing n steps, dt), or None without PyElastica."""
    try:
        import elastica  # noqa: F401
    except ImportError:
        return None
    dt = 1.13e-4  # half the largest stable step at E = 1e6 (docs/performance.md)
    return bench_pyelastica.pyelastica_stepper(E, dt, N_EL), dt


def head_to_head(pe_run, k_list, T1, rounds):
    """PyElastica's step and the fast step at 100 planar elements, timed in alternating blocks (cheapest block of
    each): the two see the same machine load."""
    fast = {k: FastRodStep(cantilever(100, T1 / k, 2)) for k in k_list}
    st = {k: fast[k].step(Simulation(fast[k].model).state) for k in k_list}
    best = {"pe": math.inf, **{k: math.inf for k in k_list}}
    for _ in range(rounds):
        t0 = time.perf_counter()
        pe_run(2000)
        best["pe"] = min(best["pe"], (time.perf_counter() - t0) / 2000)
        for k in k_list:
            t0 = time.perf_counter()
            for _ in range(100):
                st[k] = fast[k].step(st[k])
            best[k] = min(best[k], (time.perf_counter() - t0) / 100)
    return best


def main():
    quick = "--quick" in sys.argv
    T1 = 2 * math.pi / reference(E)
    h = T1 / 64
    sizes = [10, 100, 1000] if quick else [10, 100, 1000, 10000, 100000]
    budget = 2e4 if quick else 4e4
    print(f"# h = T1/64 = {h:.4g} s (T1 = {T1:.4g} s); one process, {'quick' if quick else 'full'} run\n")
    rows = {}
    print("| model | elements | steps timed | stepper µs/step | it./step | Jac./step | fast µs/step | it./step | "
          "Jac./step | stepper / fast | max rel. diff. of q |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for dim in (2, 3):
        for N in sizes:
            n = steps_for(N, budget)
            model = cantilever(N, h, dim)
            t_old, it_old, j_old, s_old = run_old(model, n)
            t_fast, it_fast, j_fast, s_fast, fb = run_fast(cantilever(N, h, dim), n)
            diff = float(np.abs(s_old.q - s_fast.q).max() / np.abs(s_old.q).max())
            rows[(dim, N)] = (t_old, t_fast)
            print(f"| {'planar' if dim == 2 else '3D'} cantilever | {N} | {n} | {t_old * 1e6:.4g} | {it_old:.2f} | "
                  f"{j_old:.2f} | {t_fast * 1e6:.4g} | {it_fast:.2f} | {j_fast:.2f} | {t_old / t_fast:.1f} | {diff:.1e}"
                  + (f" ({fb} fallbacks)" if fb else "") + " |", flush=True)
    print()
    big = [N for N in sizes if N >= 100]
    if len(big) >= 2:
        print("| model | path | slope of log(cost) against log(nodes), "
              f"{big[0]}-{big[-1]} elements |")
        print("|---|---|---|")
        for dim in (2, 3):
            x = np.log([N + 1 for N in big])
            for k, name in ((0, "stepper"), (1, "fast")):
                y = np.log([rows[(dim, N)][k] for N in big])
                slope = np.polyfit(x, y, 1)[0]
                print(f"| {'planar' if dim == 2 else '3D'} | {name} | {slope:.3f} |")
        print()
    print("| planar, 100 elements: steps per first period | h [s] | fast µs/step | it./step | Jac./step |")
    print("|---|---|---|---|---|")
    per_period = {}
    for k in (16, 64, 256, 1024, 4096):
        t_k, it_k, j_k, _, _ = run_fast(cantilever(100, T1 / k, 2), 400)
        per_period[k] = t_k
        print(f"| {k} | {T1 / k:.3g} | {t_k * 1e6:.4g} | {it_k:.2f} | {j_k:.2f} |", flush=True)
    print()
    pe = pyelastica_stepper()
    if pe is None:
        print("PyElastica not installed: pip install -e '.[compare]'")
        return
    pe_run, dt_pe = pe
    ks = (64, 1024, 4096)
    best = head_to_head(pe_run, ks, T1, 3 if quick else 8)
    t_pe = best["pe"]
    t_old = rows[(2, 100)][0]
    print("| 100 elements, planar (alternating blocks) | µs/step | ratio to PyElastica's step | step [s] | "
          "wall per simulated s |")
    print("|---|---|---|---|---|")
    print(f"| PyElastica PositionVerlet | {t_pe * 1e6:.4g} | 1 | {dt_pe:.3g} | {t_pe / dt_pe:.3g} |")
    print(f"| varint stepper, 64 steps per period (table above) | {t_old * 1e6:.4g} | {t_old / t_pe:.1f} | {h:.3g} | "
          f"{t_old / h:.3g} |")
    for k in ks:
        print(f"| varint fast step, {k} steps per period | {best[k] * 1e6:.4g} | {best[k] / t_pe:.1f} | {T1 / k:.3g} | "
              f"{best[k] / (T1 / k):.3g} |")

if __name__ == "__main__":
    main()
