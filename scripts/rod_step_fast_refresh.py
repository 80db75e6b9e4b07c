"""The compiled rod step's chord iteration: its contraction, and the finite-difference Jacobian refresh (counts).

docs/theory.md §9 "Jacobian refresh", docs/performance.md "The compiled rod step".  Case: PyElastica's cantilever of
scripts/bench_rod_step_fast.py (released from the first mode shape), h = T1/k.  Everything printed here is a count
or a norm, deterministic (no timing): the cost ratios are scripts/bench_rod_step_vs_commit.py's.

  --contraction   at 100 planar elements, 64 steps per period: the error of each chord iterate on the kept
                  factorisation (scaled as Newton's test: b by ds, xi by 1), median over the steps, against the
                  converged z; the same with the exact Jacobian at the step's solution, and the spectral radius of
                  I - J_old^-1 J against the age of the factorisation (steps since it was made)
  (default)       iterations, exact and finite-difference Jacobians and residuals per step, the rate rule alone
                  (fd_refresh=False, the step before the refresh) against the default, and the largest relative
                  difference of the two runs' positions and frames
  --timing        the two alternately in one process, each round the same stretch of the motion from the same state
                  (cheapest of --rounds each): their cost ratio (fd_refresh=False is bit for bit the step before;
                  scripts/bench_rod_step_vs_commit.py loads that step itself from git)

Run:  python scripts/rod_step_fast_refresh.py [--contraction | --timing] [--steps 256] [--rounds 10]
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent
sys.path.insert(0, str(ROOT))

from bench_pyelastica import reference  # noqa: E402
from bench_rod_step_fast import E, cantilever  # noqa: E402

from varint import Simulation  # noqa: E402
from varint.schemes.rod_compiled import FastRodStep, _k_band_solve  # noqa: E402

T1 = 2 * math.pi / reference(E)


def run(N, k, dim, steps, **kw):
    fast = FastRodStep(cantilever(N, T1 / k, dim), **kw)
    st = fast.step(Simulation(fast.model).state)
    c = np.zeros(4)
    for _ in range(steps):
        st = fast.step(st)
        c += [fast.last["iterations"], fast.last["n_jacobian"] - fast.last["n_jacobian_fd"], fast.last["n_jacobian_fd"],
              fast.last["n_residual"]]
    return c / steps, st, fast.fallbacks


CONFIGS = [(2, N, 64) for N in (10, 25, 50, 100, 200, 400)] + [(2, 100, k) for k in (16, 256, 1024, 4096)]
CONFIGS += [(3, 100, 64), (3, 400, 64)]


def timing(rounds):
    """Each round runs both steps over the same stretch of the motion from the same state (after invalidate(): the
    same arithmetic every round), the cheapest round of each counts.  Not blocks of a continuing run: the iterations
    of the step before vary with the phase of the motion (4 to 8 at 1024 steps per period), those after much less,
    so the cheapest of consecutive blocks would compare different phases."""
    print("| model | elements | steps per period | steps timed | before µs/step | after µs/step | after / before |")
    print("|---|---|---|---|---|---|---|")
    for dim, N, k in CONFIGS:
        steps = max(128, min(k // 2, 20000 // N))
        runs = {}
        for fd in (False, True):
            f = FastRodStep(cantilever(N, T1 / k, dim), fd_refresh=fd)
            st0 = f.step(Simulation(f.model).state)
            for _ in range(32):
                st0 = f.step(st0)
            runs[fd] = [f, st0, math.inf]
        for _ in range(rounds):
            for fd in (False, True):
                r = runs[fd]
                f = r[0]
                f.invalidate()
                st = f.step(r[1])  # the first Jacobian, untimed
                t0 = time.perf_counter()
                for _ in range(steps):
                    st = f.step(st)
                r[2] = min(r[2], (time.perf_counter() - t0) / steps)
        b, a = runs[False][2], runs[True][2]
        print(f"| {'planar' if dim == 2 else '3D'} | {N} | {k} | {steps} | {b * 1e6:.1f} | {a * 1e6:.1f} | {a / b:.3f} |",
              flush=True)


def counts(steps):
    print("| model | elements | steps per period | it./step before | after | complex-step Jac./step before | after | "
          "FD Jac./step after | residuals/step before | after | max rel. diff. of q |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for dim, N, k in CONFIGS:
        b, sb, fb_b = run(N, k, dim, steps, fd_refresh=False)
        a, sa, fb_a = run(N, k, dim, steps)
        diff = float(np.abs(sa.q - sb.q).max() / np.abs(sb.q).max())
        fb = f" ({fb_b}/{fb_a} fallbacks)" if fb_a or fb_b else ""
        print(f"| {'planar' if dim == 2 else '3D'} | {N} | {k} | {b[0]:.2f} | {a[0]:.2f} | {b[1]:.3f} | {a[1]:.3f} | "
              f"{a[2]:.3f} | {b[3]:.2f} | {a[3]:.2f} | {diff:.1e}{fb} |", flush=True)


def contraction(steps):
    fast = FastRodStep(cantilever(100, T1 / 64, 2), fd_refresh=False)
    st = fast.step(Simulation(fast.model).state)
    for _ in range(30):
        st = fast.step(st)
    kept, fresh, its = [], [], []
    for s in range(steps):
        have = fast.ci[7]
        ab, ipiv = fast.ab.copy(), fast.ipiv.copy()
        z0 = fast.predict(st)
        st1 = fast.step(st)
        its.append(fast.last["iterations"])
        zs = fast.z.copy()
        if have and fast.last["n_jacobian"] == 0:
            F = lambda z: fast.residual(st.q, st.p, z)  # noqa: E731

            def chord(solve):
                z, e = z0.copy(), [np.max(np.abs(z0 - zs) / fast.scale)]
                for _ in range(9):
                    z -= solve(F(z))
                    e.append(np.max(np.abs(z - zs) / fast.scale))
                return e

            def kept_solve(r):
                b = r.copy()
                _k_band_solve(ab, fast.kl, fast.ku, ipiv, b)
                return b

            kept.append(chord(kept_solve))
            if s % 8 == 0:
                A = fast.jacobian(st.q, zs)
                fresh.append(chord(lambda r: np.linalg.solve(A, r)))
        st = st1
    np.set_printoptions(precision=1, linewidth=200)
    print(f"iterations per step (rate rule alone): {np.mean(its):.2f}")
    print("chord iterate error, kept factorisation (median):", np.median(kept, axis=0))
    print("chord iterate error, exact J at the solution  (median):", np.median(fresh, axis=0))
    # the spectral radius of I - J_old^-1 J against the factorisation's age
    Js = []
    for _ in range(40):
        st1 = fast.step(st)
        Js.append(fast.jacobian(st.q, fast.z))
        st = st1
    for age in (1, 2, 4, 8, 16, 32):
        rho = [np.abs(np.linalg.eigvals(np.eye(fast.nz) - np.linalg.solve(Js[s - age], Js[s]))).max()
               for s in range(32, 40, 2)]
        print(f"age {age:2d}: spectral radius of I - J_old^-1 J = {np.median(rho):.2e}")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--contraction", action="store_true")
    ap.add_argument("--timing", action="store_true")
    ap.add_argument("--steps", type=int, default=256)
    ap.add_argument("--rounds", type=int, default=10)
    args = ap.parse_args()
    if args.timing:
        timing(args.rounds)
    else:
        (contraction if args.contraction else counts)(args.steps)


if __name__ == "__main__":
    main()
