"""PNG figures of a run file: monitors against time and space-time maps of p, u, R."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .io import read_run

__all__ = ["plot_run", "monitor_panels"]


def monitor_panels(mon):
    """[(axis label, [(curve name, values), ...]), ...] for a run's monitors.

    Tube runs: energy and mass errors, the fluid's axial momentum, Newton iterations.  Rod runs
    (they have ``frame_orthogonality``): energy error and terms, the changes of linear momentum and of
    angular momentum about the centre of mass (reactions of supports included), frame
    orthogonality, Newton iterations.
    """
    def rel(y):
        return (y - y[0]) / abs(y[0]) if y[0] != 0 else y - y[0]

    def change(y):
        return np.linalg.norm(y - y[0], axis=1)

    panels = []
    if "frame_orthogonality" in mon:
        panels.append(("relative energy error", [("energy", rel(mon["energy"]))]))
        terms = [(k.replace("energy_", ""), mon[k]) for k in ("kinetic_energy", "energy_bending_torsion", "energy_stretch_shear",
                                                             "energy_gravity", "energy_load") if k in mon and np.any(mon[k])]
        panels.append(("energy terms [J]", terms))
        panels.append(("change of linear momentum [kg m/s]", [("|P - P0|", change(mon["linear_momentum"]))]))
        if "angular_momentum_cm" in mon:
            panels.append(("change of angular momentum [kg m2/s]", [("|J_cm - J_cm0|", change(mon["angular_momentum_cm"]))]))
        panels.append(("frame orthogonality |L^T L - I|", [("max over nodes", mon["frame_orthogonality"])]))
    else:
        for name, label in (("energy", "relative energy error"), ("mass", "relative mass error")):
            if name in mon:
                panels.append((label, [(name, rel(mon[name]))]))
        if "linear_momentum" in mon:
            panels.append(("fluid momentum [kg m/s]", [("x", mon["linear_momentum"][:, 0])]))
    if "newton_iterations" in mon:
        panels.append(("Newton iterations", [("per step", mon["newton_iterations"])]))
    return panels


def plot_run(path, outdir=None):
    """Write ``<stem>_monitors.png`` and ``<stem>_fields.png``; returns their paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    run = read_run(path)
    t = run["time"]
    mon, fld = run["monitors"], run["fields"]
    stem = Path(path).stem
    outdir = Path(outdir) if outdir else Path(path).resolve().parent
    outdir.mkdir(parents=True, exist_ok=True)
    written = []

    panels = monitor_panels(mon)
    ncol = 3 if len(panels) > 4 else 2
    fig, axes = plt.subplots(2, ncol, figsize=(5 * ncol, 6.5), constrained_layout=True)
    for ax in axes.flat[len(panels):]:
        ax.set_visible(False)
    for ax, (label, curves) in zip(axes.flat, panels):
        for name, y in curves:
            ax.plot(t, y, lw=1, label=name)
        if len(curves) > 1:
            ax.legend(fontsize=7)
        if label.startswith(("change", "frame")) and np.all(np.concatenate([c[1] for c in curves]) >= 0):
            ax.set_yscale("symlog", linthresh=1e-16)  # round-off-sized quantities: show their decades
        ax.set_xlabel("t [s]")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    fig.suptitle(run["attrs"].get("title", stem), fontsize=10)
    p = outdir / f"{stem}_monitors.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    written.append(p)

    if "rod/r" in fld:
        r = fld["rod/r"]
        fig, axes = plt.subplots(1, 2, figsize=(10, 4.5), constrained_layout=True)
        picks = np.unique(np.linspace(0, len(t) - 1, min(len(t), 8)).astype(int))
        cmap = plt.get_cmap("viridis")
        for i, k in enumerate(picks):
            c = cmap(i / max(len(picks) - 1, 1))
            axes[0].plot(r[k, :, 0], r[k, :, 1], color=c, label=f"t = {t[k]:.3g} s")
            axes[1].plot(r[k, :, 0], r[k, :, 2], color=c)
        for ax, lab in zip(axes, ("y", "z")):
            ax.set_xlabel("x [m]")
            ax.set_ylabel(f"{lab} [m]")
            ax.set_aspect("equal", adjustable="datalim")
            ax.grid(alpha=0.3)
        axes[0].legend(fontsize=7)
        fig.suptitle("centreline snapshots", fontsize=10)
        p = outdir / f"{stem}_fields.png"
        fig.savefig(p, dpi=110)
        plt.close(fig)
        written.append(p)

    maps = []
    if "fluid/pressure" in fld:
        s = fld["fluid/s"]
        centres = 0.5 * (s[:, 1:] + s[:, :-1])
        maps.append(("pressure [Pa]", centres, fld["fluid/pressure"]))
        maps.append(("velocity [m/s]", s, fld["fluid/velocity"]))
    if "wall/R" in fld:
        R = fld["wall/R"]
        x = np.linspace(0.0, 1.0, R.shape[1])[None, :] * np.ones((R.shape[0], 1))
        L = float(s[0, -1] - s[0, 0]) if "fluid/s" in fld else 1.0
        maps.append(("R - R(t=0) [m]", x * L, R - R[0]))
    if maps and len(t) > 1:
        fig, axes = plt.subplots(1, len(maps), figsize=(4.2 * len(maps), 4.2), constrained_layout=True, squeeze=False)
        for ax, (label, x, y) in zip(axes[0], maps):
            xg = np.linspace(np.min(x[0]), np.max(x[0]), max(200, y.shape[1]))
            img = np.array([np.interp(xg, xi, yi) for xi, yi in zip(x, y)])
            im = ax.pcolormesh(xg, t, img, shading="auto", cmap="RdBu_r")
            fig.colorbar(im, ax=ax)
            ax.set_title(label, fontsize=9)
            ax.set_xlabel("s [m]")
            ax.set_ylabel("t [s]")
        p = outdir / f"{stem}_fields.png"
        fig.savefig(p, dpi=110)
        plt.close(fig)
        written.append(p)
    return written
