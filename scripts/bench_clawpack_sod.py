"""varint's [shock_capturing] against PyClaw's classic solver on shock tubes, side by side in one run.

Cases (on [0, 1], diaphragm at 0.5, gamma = 1.4, the data of scripts/shock_tube_convergence.py):
Sod, (rho, u, p) = (1, 0, 1) | (0.125, 0, 0.1) to t = 0.2, and the pressure-ratio-100 tube,
(1, 0, 10) | (0.125, 0, 0.1) to t = 0.1 (Toro's test 3, ``ratio1e5``, on request with --cases).

varint: exactly as scripts/shock_tube_convergence.py runs it (its scene, c_Q = 1, c_L = 0.5, fixed step at
CFL 0.5 on the largest initial sound speed, N parcels of equal length at t = 0, closed ends).

PyClaw (Clawpack 5.x, the optional ``compare`` extra, never a dependency of varint): ClawSolver1D with
the Fortran kernels, the Roe solver with the Harten-Hyman entropy fix (``riemann.euler_with_efix_1D``),
second-order Lax-Wendroff corrections with the MC limiter on the waves, variable step with
cfl_desired = 0.9 (cfl_max = 1.0), N equal cells on [0, 1], extrapolation boundaries (no wave reaches
them by the final time).

Measured per tool, case and N = 100 ... 3200 (the two tools alternate at every N, the first one
swapped from N to N, so that slow drifts of the machine's load hit both):
* CPU time of the solve only: ``time.process_time()`` around varint's step loop and around PyClaw's
  ``solver.evolve_to_time`` after ``solver.setup`` (scene parsing, model building, PyClaw's grid and
  initial data, and numba compilation / the f2py import (a warm-up run at N = 20) are excluded); best
  of up to 5 repeats while the repeats add up to < 0.5 s (so only the fast small-N runs are repeated).
  The process is pinned to one core and numba / BLAS / OpenMP to one thread.
* density L1 error against the exact Riemann solution (varint.exact.shocks.RiemannSolution), the same
  sampling for both: each solution piecewise constant on its own cells (PyClaw) or parcels (varint),
  |rho - exact| integrated on 400 000 equal sub-intervals of [0, 1]
  (``varint.analysis.shock_measure.density_l1``);
* the contact's width: cells / parcels near the exact contact whose density lies strictly inside its
  jump, 5 % of the jump off either plateau (``shock_tube_convergence.contact_cells``).

After the N list, PyClaw alone goes on doubling N until its CPU time passes varint's largest (--no-extra:
not), so that PyClaw's error at varint's CPU time is interpolated, not extrapolated; those runs are
sampled on 64 sub-intervals per cell (aligned with the cells).

Prints markdown tables (at equal N: errors, CPU times, their ratios varint / PyClaw, contact widths;
at varint's CPU times: PyClaw's error interpolated log-log between its N, and the CPU time PyClaw needs
for varint's error) and writes the work-precision plot docs/shock_work_precision.png.

PyClaw:  pip install -e '.[compare]'   (builds Fortran: needs gfortran)
Run:     python scripts/bench_clawpack_sod.py [--cases sod,ratio100] [--max 3200] [--no-extra] [--plot PATH]
"""

from __future__ import annotations

import os

# one core, one thread: set before numpy / numba are imported
for _v in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "scripts"))

from shock_tube_convergence import CASES, GAMMA, SAMPLES, contact_cells, scene_text  # noqa: E402

from varint import Simulation, build_model, parse_scene  # noqa: E402
from varint.analysis.shock_measure import density_l1  # noqa: E402
from varint.exact.shocks import RiemannSolution  # noqa: E402

PYCLAW_CFL = 0.9
VARINT_CFL = 0.5


def best_cpu(solve, prepare, budget=0.5, repeats=5):
    """Smallest CPU time of ``solve(prepare())`` over up to ``repeats`` runs adding up to < ``budget`` s.

    Returns (cpu, wall, the last run's result).  Only ``solve`` is timed.
    """
    best_cpu_t, best_wall, spent = math.inf, math.inf, 0.0
    for _ in range(repeats):
        obj = prepare()
        c0, w0 = time.process_time(), time.perf_counter()
        out = solve(obj)
        c, w = time.process_time() - c0, time.perf_counter() - w0
        best_cpu_t, best_wall, spent = min(best_cpu_t, c), min(best_wall, w), spent + c
        if spent > budget:
            break
    return best_cpu_t, best_wall, out


# ----------------------------------------------------------------------------- varint


def varint_run(case, N, cfl=VARINT_CFL):
    """varint at N parcels, as scripts/shock_tube_convergence.py runs it; returns a result dict."""
    left, right, end = CASES[case]
    text, n = scene_text(N, left, right, end, cfl, 1.0, 0.5)

    def prepare():
        return Simulation(build_model(parse_scene(text)))

    def solve(sim):
        for _ in range(n):
            sim.step()
        return sim

    cpu, wall, sim = best_cpu(solve, prepare)
    model, st = sim.model, sim.state
    cfg = model.tube.config(np.concatenate([st.q[model.tube_q], st.lam]))
    rho, p, _ = model.tube.fluid_fields(cfg, st.p[model.tube_p])
    exact = RiemannSolution(left, right, GAMMA)
    return {"edges": np.asarray(cfg.s), "rho": rho, "cpu": cpu, "wall": wall, "steps": n,
            "l1": density_l1(cfg.s, rho, exact, end, SAMPLES), "contact": contact_cells(cfg.s, rho, exact, end),
            "rho_min": float(rho.min()), "p_min": float(p.min())}


# ----------------------------------------------------------------------------- PyClaw


def import_pyclaw():
    """clawpack.pyclaw, imported from the temporary directory: its logging setup opens ./pyclaw.log."""
    import tempfile

    here = os.getcwd()
    os.chdir(tempfile.gettempdir())
    try:
        from clawpack import pyclaw
    finally:
        os.chdir(here)
    return pyclaw


def pyclaw_setup(case, N, cfl=PYCLAW_CFL):
    """PyClaw's classic solver and the initial Solution for ``case`` on N cells (not timed)."""
    from clawpack import riemann

    pyclaw = import_pyclaw()
    from clawpack.riemann.euler_with_efix_1D_constants import density, energy, momentum, num_eqn

    left, right, _ = CASES[case]
    solver = pyclaw.ClawSolver1D(riemann.euler_with_efix_1D)  # Roe + Harten-Hyman entropy fix
    solver.kernel_language = "Fortran"
    solver.limiters = pyclaw.limiters.tvd.MC
    solver.order = 2
    solver.cfl_desired, solver.cfl_max = cfl, 1.0
    solver.bc_lower[0] = solver.bc_upper[0] = pyclaw.BC.extrap
    solver.verbosity = 0
    dim = pyclaw.Dimension(0.0, 1.0, N, name="x")
    domain = pyclaw.Domain([dim])
    state = pyclaw.State(domain, num_eqn)
    state.problem_data["gamma"] = GAMMA
    state.problem_data["gamma1"] = GAMMA - 1.0
    xc = state.grid.x.centers
    on_left = xc < 0.5
    rho = np.where(on_left, left[0], right[0])
    u = np.where(on_left, left[1], right[1])
    p = np.where(on_left, left[2], right[2])
    state.q[density, :] = rho
    state.q[momentum, :] = rho * u
    state.q[energy, :] = p / (GAMMA - 1.0) + 0.5 * rho * u ** 2
    solution = pyclaw.Solution(state, domain)
    # first step near the CFL target, so no step is rejected at the start
    cmax = max(math.sqrt(GAMMA * s[2] / s[0]) + abs(s[1]) for s in (left, right))
    solver.dt_initial = cfl / (N * cmax)
    solver.max_steps = 100000
    solver.setup(solution)  # loads the Fortran module, sets the cparam common block (not timed)
    return solver, solution


def pyclaw_run(case, N, cfl=PYCLAW_CFL, samples=SAMPLES):
    from clawpack.riemann.euler_with_efix_1D_constants import density, energy, momentum

    left, right, end = CASES[case]

    def solve(obj):
        solver, solution = obj
        solver.evolve_to_time(solution, end)
        return obj

    cpu, wall, (solver, solution) = best_cpu(solve, lambda: pyclaw_setup(case, N, cfl))
    q = solution.state.q
    rho = q[density].copy()
    p = (GAMMA - 1.0) * (q[energy] - 0.5 * q[momentum] ** 2 / rho)
    edges = np.linspace(0.0, 1.0, N + 1)
    exact = RiemannSolution(left, right, GAMMA)
    assert abs(solution.t - end) < 1e-12 * end, solution.t
    return {"edges": edges, "rho": rho, "cpu": cpu, "wall": wall, "steps": solver.status["numsteps"],
            "l1": density_l1(edges, rho, exact, end, samples), "contact": contact_cells(edges, rho, exact, end),
            "rho_min": float(rho.min()), "p_min": float(p.min())}


# ----------------------------------------------------------------------------- comparison


def loglog_at(x, xs, ys):
    """ys(x) interpolated linearly in log-log over the points (xs, ys); up to a factor 2 beyond them, the
    end segment's power law extended; further out, None.  Returns (value, extrapolated?)."""
    order = np.argsort(xs)
    lx, ly = np.log(np.asarray(xs)[order]), np.log(np.asarray(ys)[order])
    t = math.log(x)
    if lx[0] <= t <= lx[-1]:
        return float(np.exp(np.interp(t, lx, ly))), False
    if not lx[0] - math.log(2.0) <= t <= lx[-1] + math.log(2.0):
        return None, True
    i = 0 if t < lx[0] else len(lx) - 2
    slope = (ly[i + 1] - ly[i]) / (lx[i + 1] - lx[i])
    return float(np.exp(ly[i] + slope * (t - lx[i]))), True


def num(x):
    """A ratio: whole above 10, two significant digits below."""
    return f"{x:.0f}" if x >= 10 else f"{x:.2g}"


def rate(prev, cur):
    return "" if prev is None else f"{math.log2(prev['l1'] / cur['l1']):.2f}"


def table(results, cases, Ns, extra):
    print("### At equal N\n")
    print("| case | N | varint L1 (rate) | PyClaw L1 (rate) | L1 ratio v/P | varint CPU s | PyClaw CPU s | "
          "CPU ratio v/P | contact cells v / P | steps v / P |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for case in cases:
        pv = pp = None
        for N in Ns:
            v, p = results[case, "varint", N], results[case, "pyclaw", N]
            print(f"| {case} | {N} | {v['l1']:.3e} ({rate(pv, v)}) | {p['l1']:.3e} ({rate(pp, p)}) | "
                  f"{v['l1'] / p['l1']:.2f} | {v['cpu']:.3f} | {p['cpu']:.4f} | {num(v['cpu'] / p['cpu'])} | "
                  f"{v['contact']} / {p['contact']} | {v['steps']} / {p['steps']} |")
            pv, pp = v, p
    if any(extra[c] for c in cases):
        print("\n### PyClaw beyond the N list (for the equal-CPU comparison only; sampled on 64 sub-intervals per cell)\n")
        print("| case | N | PyClaw L1 | PyClaw CPU s | contact cells | steps |")
        print("|---|---|---|---|---|---|")
        for case in cases:
            for N in extra[case]:
                p = results[case, "pyclaw", N]
                print(f"| {case} | {N} | {p['l1']:.3e} | {p['cpu']:.3f} | {p['contact']} | {p['steps']} |")
    print("\n### At equal CPU time and at equal error (PyClaw interpolated log-log between its N)\n")
    print("| case | varint N | varint CPU s | varint L1 | PyClaw L1 at that CPU | L1 ratio v/P | "
          "PyClaw CPU for varint's L1 | CPU ratio v/P at equal L1 |")
    print("|---|---|---|---|---|---|---|---|")
    for case in cases:
        P = [results[case, "pyclaw", N] for N in Ns + extra[case]]
        cpu, l1 = [r["cpu"] for r in P], [r["l1"] for r in P]
        for N in Ns:
            v = results[case, "varint", N]
            at, x1 = loglog_at(v["cpu"], cpu, l1)
            c_at, x2 = loglog_at(v["l1"], l1, cpu)
            m1, m2 = ("*" if x1 else ""), ("*" if x2 else "")
            a1 = "— | —" if at is None else f"{at:.2e}{m1} | {v['l1'] / at:.1f}{m1}"
            a2 = "— | —" if c_at is None else f"{c_at:.4f}{m2} | {num(v['cpu'] / c_at)}{m2}"
            print(f"| {case} | {N} | {v['cpu']:.3f} | {v['l1']:.3e} | {a1} | {a2} |")
    print("\n(*: up to 2x outside PyClaw's measured range, its end segment's power law extended; —: further out.)")


def plot(results, cases, Ns, extra, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    titles = {"sod": "Sod, t = 0.2", "ratio100": "pressure ratio 100, t = 0.1", "ratio1e5": "Toro 3 (ratio 1e5), t = 0.012"}
    fig, axes = plt.subplots(1, len(cases), figsize=(5.2 * len(cases), 4.2), squeeze=False)
    for ax, case in zip(axes[0], cases):
        for tool, style, label in (("varint", "o-", "varint [shock_capturing], CFL 0.5"),
                                   ("pyclaw", "s--", f"PyClaw classic, Roe + MC, CFL {PYCLAW_CFL}")):
            NN = Ns + (extra[case] if tool == "pyclaw" else [])
            cpu = [results[case, tool, N]["cpu"] for N in NN]
            err = [results[case, tool, N]["l1"] for N in NN]
            ax.loglog(cpu, err, style, label=label)
            for N, c, e in zip(NN, cpu, err):
                ax.annotate(str(N), (c, e), textcoords="offset points", xytext=(4, 4), fontsize=7)
        ax.set_xlabel("CPU time of the solve [s]")
        ax.set_ylabel("density L1 error")
        ax.set_title(titles.get(case, case))
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    print(f"\nwork-precision plot: {path}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", default="sod,ratio100")
    ap.add_argument("--max", type=int, default=3200, help="largest N (default 3200)")
    ap.add_argument("--plot", default=str(ROOT / "docs" / "shock_work_precision.png"))
    ap.add_argument("--no-plot", action="store_true")
    ap.add_argument("--no-extra", action="store_true", help="no PyClaw runs beyond --max")
    ap.add_argument("--core", type=int, default=None, help="pin to this core (default: the last one)")
    args = ap.parse_args()
    try:
        import clawpack  # noqa: F401
    except ImportError:
        sys.exit("PyClaw is not installed: pip install -e '.[compare]' (needs gfortran)")
    if hasattr(os, "sched_setaffinity"):
        cores = sorted(os.sched_getaffinity(0))
        os.sched_setaffinity(0, {cores[-1] if args.core is None else args.core})
    cases = args.cases.split(",")
    Ns = [N for N in (100, 200, 400, 800, 1600, 3200, 6400, 12800) if N <= args.max]

    varint_run("sod", 20)  # numba compilation outside the timings
    pyclaw_run("sod", 20)  # the f2py modules' import
    import clawpack

    print(f"varint: c_Q = 1, c_L = 0.5, CFL {VARINT_CFL} (fixed step). PyClaw {clawpack.__version__}: classic, "
          f"Roe + entropy fix, MC limiter, CFL {PYCLAW_CFL} (variable step). One core "
          f"(affinity {sorted(os.sched_getaffinity(0))}); CPU = process_time of the solve, best of <= 5 "
          "repeats within 0.5 s.", flush=True)
    results, extra = {}, {case: [] for case in cases}
    first = "varint"
    t_start = time.perf_counter()

    def record(case, tool, N, r):
        results[case, tool, N] = r
        print(f"  {case} N={N} {tool}: L1 {r['l1']:.3e}, CPU {r['cpu']:.4f} s (wall {r['wall']:.4f}), "
              f"contact {r['contact']}, steps {r['steps']}, min rho {r['rho_min']:.4g}, min p {r['p_min']:.4g}",
              file=sys.stderr, flush=True)

    for case in cases:
        for N in Ns:
            order = ("varint", "pyclaw") if first == "varint" else ("pyclaw", "varint")
            for tool in order:
                record(case, tool, N, (varint_run if tool == "varint" else pyclaw_run)(case, N))
            first = order[1]
        # PyClaw on, doubling N, until its CPU time passes varint's largest: equal-CPU by interpolation
        N, top = Ns[-1], results[case, "varint", Ns[-1]]["cpu"]
        while not args.no_extra and results[case, "pyclaw", N]["cpu"] < top and N < 16 * Ns[-1]:
            N *= 2
            record(case, "pyclaw", N, pyclaw_run(case, N, samples=64 * N + 1))  # sub-intervals on the cells
            extra[case].append(N)
    print(f"\n(all runs: {time.perf_counter() - t_start:.0f} s wall)\n")
    table(results, cases, Ns, extra)
    if not args.no_plot:
        plot(results, cases, Ns, extra, args.plot)


if __name__ == "__main__":
    main()
