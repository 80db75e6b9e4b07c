"""The stability diagram of the cantilevered pipe conveying fluid, u_cr(beta), from one ``varint sweep --analysis
modes`` against varint/exact/pipe_stability.py (Païdoussis eq. 3.70; Gregory & Païdoussis 1966): docs/validation.md,
docs/pipe_stability_diagram.png.

The scene is the pipe of tests/test_flowing_modes.py (L = 1, EI = 1, nearly inextensible, planar, 40 elements)
with the liquid's mass per length fixed at M = 0.5, so that one sweep key sets each parameter:
rod.mass_per_length = m = M (1 - beta)/beta sets beta = M/(M + m), and fluid.velocity = U sets u = U sqrt(M).
The sweep runs every (beta, u) point of the product on a local Dask cluster (``varint sweep``, unchanged); from
its table, for each beta, u_cr is the first u where the largest growth rate turns positive (linear interpolation
of the growth rate between the bracketing points) and the instability windows are the runs of points with
growth_rate > 0.  The truth: ``pipe_stability.critical_flow_velocity`` (first loss of stability, Galerkin with
40 beam modes, u step 0.01) at each beta, and the zero contour of the largest Galerkin growth rate over a finer
(beta, u) grid for the S-shaped parts, where the pipe regains stability above u_cr.

    python scripts/pipe_stability_diagram.py [--out DIR] [--workers 2] [--nodes 41] [--du 0.25]

Writes DIR/sweep.csv (kept: a re-run skips finished points), DIR/diagram.csv and docs/pipe_stability_diagram.png,
and prints the u_cr(beta) table with the errors.
"""

import argparse
import csv
import os
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))

from varint.scene.standard import pipe_scene_text as pipe_text  # noqa: E402

from varint.exact import pipe_stability as ps  # noqa: E402

M_FLUID = 0.5


def betas():
    """48 values over 0.05..0.95 and the neighbourhoods of the S-shaped parts (beta ~ 0.30, 0.69, 0.92)."""
    b = set(np.round(np.arange(0.05, 0.951, 0.025), 4))
    b |= {0.28, 0.29, 0.3, 0.31, 0.32, 0.67, 0.68, 0.69, 0.7, 0.71, 0.9, 0.91, 0.92, 0.93}
    return np.array(sorted(b))


def galerkin_growth(beta, u, n_modes=20):
    """The largest dimensionless growth rate -Im omega of pipe_stability's Galerkin eigenvalues (the lower half,
    |omega| < 300, which are converged)."""
    om = ps.eigenvalues(u, beta, "clamped-free", n_modes=n_modes)
    om = om[np.abs(om) < 300.0]
    return float(np.max(-om.imag))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default="/tmp/pipe_stability_sweep")
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--nodes", type=int, default=41)
    ap.add_argument("--du", type=float, default=0.25)
    ap.add_argument("--umin", type=float, default=3.5)
    ap.add_argument("--umax", type=float, default=20.0)
    ap.add_argument("--png", default=os.path.join(HERE, "..", "docs", "pipe_stability_diagram.png"))
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)
    B = betas()
    us = np.round(np.arange(args.umin, args.umax + 1e-9, args.du), 6)
    scene = os.path.join(args.out, "pipe.toml")
    # beta = M/(M+m) through rod.mass_per_length; u = U sqrt(M) through fluid.velocity (EI = L = 1)
    with open(scene, "w") as f:
        f.write(pipe_text(("clamped", "free"), M_FLUID, 1.0, args.nodes, 2))
    masses = [repr(float(M_FLUID * (1 - b) / b)) for b in B]
    speeds = [repr(float(u / np.sqrt(M_FLUID))) for u in us]
    cmd = [sys.executable, "-m", "varint", "sweep", scene, "--analysis", "modes", "--out", args.out, "-n", "8",
           "--vary", "rod.mass_per_length=" + ",".join(masses), "--vary", "fluid.velocity=" + ",".join(speeds)]
    if args.workers:
        cmd += ["--workers", str(args.workers)]
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True)
    wall = time.perf_counter() - t0
    print(f"# sweep of {len(B)} x {len(us)} = {len(B) * len(us)} points: {wall:.0f} s wall", file=sys.stderr)

    with open(os.path.join(args.out, "sweep.csv")) as f:
        rows = list(csv.DictReader(f))
    grid = np.full((len(B), len(us)), np.nan)
    mi = {round(float(v), 12): i for i, v in enumerate(masses)}
    ui = {round(float(v), 12): j for j, v in enumerate(speeds)}
    failed = 0
    for r in rows:
        if r.get("status", "ok") != "ok":
            failed += 1
            continue
        i = mi[round(float(r["rod.mass_per_length"]), 12)]
        j = ui[round(float(r["fluid.velocity"]), 12)]
        grid[i, j] = float(r["growth_rate"])
    # first crossing of each beta
    ucr = np.full(len(B), np.nan)
    for i in range(len(B)):
        g = grid[i]
        k = np.flatnonzero(g > 0.0)
        if len(k) and k[0] > 0:
            a = k[0] - 1
            ucr[i] = us[a] + (us[a + 1] - us[a]) * (-g[a]) / (g[a + 1] - g[a])
    truth = np.array([ps.critical_flow_velocity(b, "clamped-free", du=0.01)[0] for b in B])
    err = ucr / truth - 1
    with open(os.path.join(args.out, "diagram.csv"), "w") as f:
        f.write("beta,u_cr_varint,u_cr_pipe_stability,relative_error\n")
        for b, a, t, e in zip(B, ucr, truth, err):
            f.write(f"{float(b)!r},{float(a)!r},{float(t)!r},{float(e)!r}\n")
    print("| beta | u_cr sweep | u_cr pipe_stability | error |")
    print("|---|---|---|---|")
    for b, a, t, e in zip(B, ucr, truth, err):
        print(f"| {b:.3f} | {a:.4f} | {t:.4f} | {e:+.2e} |")
    ok = np.isfinite(err)
    print(f"# {ok.sum()} of {len(B)} betas with a crossing in the grid; |error| median {np.median(np.abs(err[ok])):.2e}, "
          f"max {np.max(np.abs(err[ok])):.2e} at beta = {B[ok][np.argmax(np.abs(err[ok]))]}; failed points {failed}",
          file=sys.stderr)

    # the independent map: the largest Galerkin growth rate over a finer grid
    bf = np.linspace(0.04, 0.96, 93)
    uf = np.arange(args.umin, args.umax + 1e-9, 0.1)
    gf = np.array([[galerkin_growth(b, u) for u in uf] for b in bf])

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 5.5))
    ax.contourf(bf, uf, (gf.T > 1e-8).astype(float), levels=[0.5, 1.5], colors=["#dddddd"])
    ax.contour(bf, uf, gf.T, levels=[1e-8], colors="k", linewidths=1.0)
    ax.plot(B, truth, "k-", lw=0.0)  # (the first crossing is the lower edge of the grey region)
    ax.contour(B, us, grid.T, levels=[0.0], colors="C3", linewidths=1.2, linestyles="--")
    ax.plot(B, ucr, "o", color="C3", ms=3.5, label="varint sweep --analysis modes: first crossing")
    ax.plot([], [], "k-", lw=1.0, label="pipe_stability (Galerkin): growth rate = 0")
    ax.plot([], [], "--", color="C3", lw=1.2, label="varint sweep: growth rate = 0")
    ax.fill_between([], [], color="#dddddd", label="unstable (pipe_stability)")
    ax.set_xlabel(r"mass ratio $\beta = M/(M+m)$")
    ax.set_ylabel(r"flow velocity $u = UL\sqrt{M/EI}$")
    ax.set_title(f"Cantilevered pipe conveying fluid: flutter boundary ({args.nodes - 1} elements, "
                 f"{len(B)} x {len(us)} points)", fontsize=10)
    ax.set_xlim(0, 1)
    ax.set_ylim(args.umin, args.umax)
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(args.png, dpi=120)
    print(f"# wrote {args.png}", file=sys.stderr)


if __name__ == "__main__":
    main()
