"""Cost of the coupled tube's fluid kernels (varint/terms/coupled.py, docs/theory.md §10.9) and of a whole
coupled step (docs/performance.md).

* kernels: ``fluid_potential_step`` (gradient only, and with its Newton block) and ``fluid_kinetic_chart``
  (the same two) on a bent, twisted closed rod of N elements carrying M = N parcels of liquid
  (incompressible, p_ext and gravity on: every branch of the potential runs) and of ideal gas, at
  N = M = 20, 100, 1000; the NumPy reference path (``fast=False``) next to the compiled one when both exist;
* a whole step: ``varint.Simulation`` on examples/water_filled_hose.toml with its nodes and parcels scaled
  (20, 100, 400 elements; the step shortened as 1/N past 20 elements: the rubber's fast modes), mean wall
  time per step over a few steps after a warm-up step, with the step term on the NumPy reference and on
  the compiled kernels (the same iterates to round-off: the iteration counts agree).

Run alone (2 cores shared otherwise distort the timings):  python scripts/bench_coupled_terms.py
"""

from __future__ import annotations

import argparse
import contextlib
import inspect
import time
from pathlib import Path

import numpy as np

from varint.terms.coupled import FluidPotential, fluid_kinetic_chart, fluid_potential_step
from varint.lattice.lie import cay
from varint.terms.thermo import IdealGas

ROOT = Path(__file__).resolve().parent.parent


def best_of(fn, repeat=5, budget=2.0):
    """Best wall time of ``fn`` over ``repeat`` runs (fewer if one run exceeds ``budget`` / repeat)."""
    best = np.inf
    t_start = time.perf_counter()
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
        if time.perf_counter() - t_start > budget:
            break
    return best


def case(n_el, M, kind="liquid", seed=3, L=1.2):
    """(FluidPotential, state) of a closed rod: as tests/test_coupled_terms.py `_case`, at any size."""
    rng = np.random.default_rng(seed)
    ds = L / n_el
    n_nodes = n_el + 1
    Lam0 = np.empty((n_nodes, 3, 3))
    r0 = np.zeros((n_nodes, 3))
    Lam0[0] = cay(0.3 * rng.normal(size=3))
    for j in range(n_el):
        Lam0[j + 1] = Lam0[j] @ cay(0.6 * ds * rng.normal(size=3))
        r0[j + 1] = r0[j] + Lam0[j] @ (np.array([1.0, 0, 0]) + 0.05 * rng.normal(size=3)) * ds
    r1 = r0 + 0.02 * ds * rng.normal(size=r0.shape)
    Lam1 = Lam0 @ cay(0.1 * ds * rng.normal(size=(n_nodes, 3)))
    R0 = 0.1 * (1 + 0.1 * rng.uniform(-1, 1, n_nodes))
    R1 = R0 * (1 + 0.02 * rng.normal(size=n_nodes))
    s0 = np.linspace(0.0, L, M + 1)
    s0[1:-1] += 0.2 * L / M * rng.uniform(-1, 1, M - 1)
    s1 = s0.copy()
    s1[1:-1] += 0.05 * L / M * rng.uniform(-1, 1, M - 1)
    m = 0.03 * rng.uniform(0.5, 1.5, M)
    mbar = np.zeros(M + 1)
    mbar[:-1] += 0.5 * m
    mbar[1:] += 0.5 * m
    g = np.array([0.3, -0.2, -9.81])
    mu = None
    if kind == "gas":
        fp = FluidPotential(ds=ds, m=m, mbar=mbar, eos=IdealGas(1.4, 287.0), S=rng.uniform(-50, 50, M), p_ext=0.4, g=g)
    else:
        V0 = np.full(M, np.pi * 0.01 * L / M)
        fp = FluidPotential(ds=ds, m=m, mbar=mbar, V0=V0, p_ext=0.4, g=g)
        mu = rng.uniform(0.5, 1.5, M)
    return fp, dict(s0=s0, r0=r0, Lam0=Lam0, R0=R0, s1=s1, r1=r1, Lam1=Lam1, R1=R1, mu=mu)


def _has_fast():
    return "fast" in inspect.signature(fluid_potential_step).parameters


def bench_kernels(sizes, kinds):
    fast_flags = [False, True] if _has_fast() else [None]
    print("kernel timings (best of 5, ms)")
    print(f"{'case':<14} {'path':<7} {'pot grad':>9} {'pot Newton':>11} {'kin grad':>9} {'kin Newton':>11}")
    for kind in kinds:
        for n in sizes:
            fp, st = case(n, n, kind)
            for fast in fast_flags:
                kw = {} if fast is None else {"fast": fast}
                # warm-up (numba compile / cache load)
                fluid_potential_step(fp, 1e-3, **st, newton=True, **kw)
                fluid_kinetic_chart(st["s0"], st["r0"], st["Lam0"], st["s1"], st["r1"], fp.mbar, 1e-3, fp.ds,
                                    newton=True, **kw)
                t = [best_of(lambda nw=nw: fluid_potential_step(fp, 1e-3, **st, newton=nw, **kw)) for nw in (False, True)]
                t += [best_of(lambda nw=nw: fluid_kinetic_chart(st["s0"], st["r0"], st["Lam0"], st["s1"], st["r1"], fp.mbar,
                                                                1e-3, fp.ds, newton=nw, **kw)) for nw in (False, True)]
                path = "-" if fast is None else ("numba" if fast else "numpy")
                print(f"{kind + ' N=M=' + str(n):<14} {path:<7} " + " ".join(f"{1e3 * x:>9.3f}" if i % 2 == 0 else
                                                                             f"{1e3 * x:>11.3f}" for i, x in enumerate(t)),
                      flush=True)


class _reference_path:
    """Within the block, the step term calls the NumPy reference (``fast=False``): the whole step as before
    the compiled kernels.  varint/terms/step.py imports the kernels at call time, so patching the module
    attributes reaches it."""

    def __enter__(self):
        import functools

        import varint.terms.coupled as ct

        self.saved = ct.fluid_potential_step, ct.fluid_kinetic_chart
        ct.fluid_potential_step = functools.partial(self.saved[0], fast=False)
        ct.fluid_kinetic_chart = functools.partial(self.saved[1], fast=False)

    def __exit__(self, *exc):
        import varint.terms.coupled as ct

        ct.fluid_potential_step, ct.fluid_kinetic_chart = self.saved


def bench_steps(elements, n_steps):
    import tomllib

    from varint import Simulation, build_model, parse_scene
    from varint.scene.text import to_toml

    base = tomllib.loads((ROOT / "examples" / "water_filled_hose.toml").read_text())
    print(f"\nwhole coupled step, examples/water_filled_hose.toml scaled (mean of {n_steps} steps after one, ms)")
    print(f"{'elements':>9} {'parcels':>8} {'path':>6} {'ms/step':>9} {'it/step':>9} {'jac/step':>9}")
    for n in elements:
        d = {k: dict(v) if isinstance(v, dict) else v for k, v in base.items()}
        d["tube"]["nodes"] = n + 1
        d["fluid"]["parcels"] = n
        # the hose's step is set by the rubber's fast modes, which stiffen as ds^-1: keep it stable
        d["time"]["step"] = base["time"]["step"] * 20 / max(n, 20)
        d["time"]["scheme"] = "midpoint"  # (the example steps with the energy-momentum scheme; this times the midpoint's)
        model = build_model(parse_scene(to_toml(d)))
        for path in ("numpy", "numba"):
            sim = Simulation(model)
            with (_reference_path() if path == "numpy" else contextlib.nullcontext()):
                sim.step()
                it0, j0 = sim.stats.total_iterations, sim.stats.total_jacobians
                t0 = time.perf_counter()
                for _ in range(n_steps):
                    sim.step()
                dt = (time.perf_counter() - t0) / n_steps
            its = (sim.stats.total_iterations - it0) / n_steps
            jac = (sim.stats.total_jacobians - j0) / n_steps
            print(f"{n:>9} {n:>8} {path:>6} {1e3 * dt:>9.2f} {its:>9.2f} {jac:>9.2f}", flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="*", default=[20, 100, 1000])
    ap.add_argument("--kinds", nargs="*", default=["liquid", "gas"])
    ap.add_argument("--steps", type=int, nargs="*", default=[20, 100, 400])
    ap.add_argument("--n-steps", type=int, default=10)
    a = ap.parse_args()
    bench_kernels(a.sizes, a.kinds)
    if a.steps:
        bench_steps(a.steps, a.n_steps)


if __name__ == "__main__":
    main()
