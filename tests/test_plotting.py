"""`varint plot`: what the figures show (scales, colour centres, single records, log axes, rod motion).

The choices are tested on the pure functions and on the artists of the figures built from run
dictionaries (as varint.run.io.read_run returns them), not on pixels; two smoke tests write the PNGs of
real run files.
"""

import math
from pathlib import Path

import numpy as np
import pytest

from helpers import rotations_about_x as _rot_x, run_record as _run
from varint.scene.standard import gas_scene
from varint.scene.text import to_toml

EPS = np.finfo(float).eps




def _shaft(K=51, n=21, amp=1e-4, whirl=20.0, spin=60.0, end=1.0):
    """A pinned shaft on the x axis spinning rigidly at `spin` about it, its centreline whirling
    (radius amp sin(pi s)) at `whirl`: (t, r (K, n, 3), Lambda (K, n, 3, 3))."""
    t = np.linspace(0.0, end, K)
    s = np.linspace(0.0, 1.0, n)
    r = np.zeros((K, n, 3))
    r[..., 0] = s
    r[..., 1] = amp * np.sin(np.pi * s)[None, :] * np.cos(whirl * t)[:, None]
    r[..., 2] = amp * np.sin(np.pi * s)[None, :] * np.sin(whirl * t)[:, None]
    Lam = np.broadcast_to(_rot_x(spin * t)[:, None], (K, n, 3, 3)).copy()
    return t, r, Lam


def _rod_monitors(K, rng, J=1.0):
    z = np.zeros(K)
    dJ = np.where(rng.random(K) < 0.3, 0.0, rng.random(K) * 3e-16)
    dJ[0] = 0.0
    return {"energy": np.full(K, 2.0), "kinetic_energy": np.full(K, 2.0), "energy_bending_torsion": z,
            "energy_load": z, "linear_momentum": np.zeros((K, 3)),
            "angular_momentum_cm": np.stack([J + dJ, z, z], axis=1),
            "frame_orthogonality": rng.choice([0.0, EPS, 2 * EPS], K), "newton_iterations": np.full(K, 3)}


# -- energy ----------------------------------------------------------------------------------------------

def _cantilever_like_monitors():
    """Released from rest and straight under a tip load: E0 ~ 1e-28 J, terms ~ 0.03 J, drift ~ 1e-8 J."""
    t = np.linspace(0.0, 4.0, 201)
    load = -0.0278 * np.sin(0.5 * t) ** 2
    bend = 0.027 * np.sin(0.5 * t) ** 2
    kin = -load - bend
    drift = 1e-8 * np.sin(3 * t)
    return t, {"energy": 1.7e-28 + drift, "kinetic_energy": kin, "energy_bending_torsion": bend, "energy_load": load,
               "energy_gravity": np.zeros_like(t)}


def test_energy_error_of_a_run_from_zero_energy_is_relative_to_the_energy_that_moves():
    from varint.plotting import monitor_panels

    t, mon = _cantilever_like_monitors()
    label, curves = next(p for p in monitor_panels(mon) if "energy error" in p[0])
    err = curves[0][1]
    # (E - E0)/|E0| would read ~6e19; against the energy that moves (max K + the potential's largest change) it is
    # the drift over that scale
    K, U = mon["kinetic_energy"], mon["energy"] - mon["kinetic_energy"]
    moving = np.max(np.abs(K)) + np.max(np.abs(U - U[0]))
    assert np.max(np.abs(err)) == pytest.approx(np.max(np.abs(mon["energy"] - mon["energy"][0])) / moving, rel=1e-12)
    assert "max K + range of U" in label  # the axis says what the error is relative to

    from varint.plotting import energy_scale

    assert energy_scale(mon) == (pytest.approx(moving, rel=1e-12), "(max K + range of U)")


def test_energy_error_is_never_relative_to_E0_even_when_E0_dominates():
    """A water-filled hose: E0 is mostly the water's p V (20 J) against 1.3 J of motion; the plot's scale is the
    motion's, as varint info's (docs/theory.md: energy errors on the motion's scale)."""
    from varint.plotting import energy_scale, monitor_panels

    K = 11
    swing = 1.3 * np.sin(np.linspace(0, 3, K)) ** 2
    mon = {"energy": 20.1 + 1e-3 * np.linspace(0, 1, K), "kinetic_energy": swing,
           "energy_gravity": 20.1 - swing + 1e-3 * np.linspace(0, 1, K)}
    label, curves = next(p for p in monitor_panels(mon) if "energy error" in p[0])
    moving = np.max(swing) + np.max(np.abs((mon["energy"] - swing) - (mon["energy"][0] - swing[0])))
    assert np.max(np.abs(curves[0][1])) == pytest.approx(1e-3 / moving, rel=1e-9)
    assert "|E0|" not in label
    assert energy_scale(mon)[0] == pytest.approx(moving, rel=1e-12)
    zero = {"energy": np.zeros(K), "kinetic_energy": np.zeros(K)}
    assert energy_scale(zero) == (1.0, None)  # nothing moves: the error in joules, not 0/0


# -- log axes --------------------------------------------------------------------------------------------

def test_round_off_panels_are_log_axes_floored_at_round_off_with_few_decades():
    from varint.plotting import monitor_panels, monitors_figure

    rng = np.random.default_rng(1)
    K = 60
    mon = _rod_monitors(K, rng, J=1.0)
    panels = {p[0]: p for p in monitor_panels(mon)}
    pJ = panels["change of angular momentum [kg m2/s]"]
    assert pJ.yscale == "log" and pJ.floor == pytest.approx(EPS * (1.0 + 3e-16))
    assert pJ[1][0][1][0] == 0.0  # the values themselves are not clipped
    assert panels["frame orthogonality |L^T L - I|"].floor == EPS
    assert panels["change of linear momentum [kg m/s]"].yscale == "linear"  # identically zero: no log

    fig = monitors_figure(_run(np.linspace(0, 1, K), mon, {}))
    for ax in fig.axes:
        if ax.get_ylabel() in ("change of angular momentum [kg m2/s]", "frame orthogonality |L^T L - I|"):
            assert ax.get_yscale() == "log"  # not symlog down to 1e-16
            lo, hi = ax.get_ylim()
            assert lo > 0 and math.log10(hi / lo) <= 3.01  # a few decades, not sixteen
            ticks = [v for v in ax.get_yticks() if lo * (1 - 1e-9) <= v <= hi * (1 + 1e-9)]
            assert 1 <= len(ticks) <= 6
            ys = np.concatenate([ln.get_ydata() for ln in ax.get_lines()])
            assert np.all(ys > 0)  # zeros drawn at the floor, never dropped to -inf


def test_large_momentum_changes_are_not_stretched_down_to_round_off():
    from varint.plotting import monitors_figure

    rng = np.random.default_rng(2)
    K = 40
    mon = _rod_monitors(K, rng)
    mon["linear_momentum"] = np.stack([np.r_[0.0, np.geomspace(1e-3, 1e-1, K - 1)], np.zeros(K), np.zeros(K)], axis=1)
    fig = monitors_figure(_run(np.linspace(0, 1, K), mon, {}))
    ax = next(a for a in fig.axes if a.get_ylabel() == "change of linear momentum [kg m/s]")
    lo, hi = ax.get_ylim()
    assert ax.get_yscale() == "log" and lo >= 1e-4 and hi <= 1.0


# -- colour scales ---------------------------------------------------------------------------------------

def _tube_run(K=30, n=40, U=0.0):
    t = np.linspace(0.0, 1e-2, K)
    s = np.linspace(0.0, 2.0, n + 1)
    sc = 0.5 * (s[1:] + s[:-1])
    p = 101325.0 + 5000.0 * np.exp(-((sc[None, :] - 1.0 - 100 * t[:, None]) / 0.08) ** 2 / 2)
    u = U + 3.0 * np.exp(-((s[None, :] - 1.0 - 100 * t[:, None]) / 0.08) ** 2 / 2)
    R = 0.05 + 1e-4 * np.exp(-((s[None, :] - 1.0 - 100 * t[:, None]) / 0.08) ** 2 / 2)
    fields = {"fluid/s": np.broadcast_to(s, (K, n + 1)).copy(), "fluid/pressure": p, "fluid/velocity": u, "wall/R": R}
    mon = {"energy": np.full(K, 5590.0), "energy_internal": np.full(K, 4000.0), "mass": np.full(K, 1.0),
           "linear_momentum": np.zeros((K, 3)), "newton_iterations": np.full(K, 4)}
    return _run(t, mon, fields, scene_toml='[tube]\nlength = 2.0\n')


def test_colour_scales_are_centred_on_the_undisturbed_state():
    from varint.plotting import diverging_limits, undisturbed

    run = _tube_run()
    p = run["fields"]["fluid/pressure"]
    c, half = diverging_limits(p)
    assert c == pytest.approx(101325.0, abs=1e-3)  # the mean at t = 0 would be 200 Pa higher: shifted by the pulse
    assert np.mean(p[0]) - 101325.0 > 100.0
    assert half == pytest.approx(np.max(np.abs(p - 101325.0)))
    assert undisturbed(run["fields"]["fluid/velocity"][0]) == 0.0  # the pulse's tails are not a mean flow
    assert undisturbed(_tube_run(U=0.7)["fields"]["fluid/velocity"][0]) == pytest.approx(0.7)
    assert diverging_limits(run["fields"]["wall/R"])[0] == pytest.approx(0.05)


def test_space_time_maps_use_a_symmetric_diverging_scale_labelled_with_what_was_subtracted():
    from matplotlib.collections import QuadMesh

    from varint.plotting import fields_figure

    fig = fields_figure(_tube_run())
    meshes = [c for ax in fig.axes if ax.get_label() != "<colorbar>" for c in ax.collections if isinstance(c, QuadMesh)]
    assert len(meshes) == 3
    for m in meshes:
        assert m.norm.vmin == pytest.approx(-m.norm.vmax) and m.norm.vmax > 0
        assert m.get_cmap().name == "RdBu_r"
    labels = " ".join(ax.get_ylabel() for ax in fig.axes) + " ".join(ax.get_title() for ax in fig.axes)
    assert "p - p0" in labels and "p0 = 101325 Pa" in labels and "R - R0" in labels and "u [m/s]" in labels


# -- single records --------------------------------------------------------------------------------------

def test_a_single_record_draws_markers_and_profiles():
    from matplotlib.collections import QuadMesh

    from varint.plotting import fields_figure, monitors_figure

    full = _tube_run()
    one = _run(full["time"][:1], {k: v[:1] for k, v in full["monitors"].items()},
               {k: v[:1] for k, v in full["fields"].items()}, scene_toml='[tube]\nlength = 2.0\n')
    fig = monitors_figure(one)
    shown = [a for a in fig.axes if a.get_visible()]
    assert shown and all(any(ln.get_marker() == "o" and len(ln.get_xdata()) == 1 for ln in a.get_lines()) for a in shown)
    fig = fields_figure(one)
    assert fig is not None
    assert not any(isinstance(c, QuadMesh) for ax in fig.axes for c in ax.collections)
    profiles = [ln for ax in fig.axes for ln in ax.get_lines() if len(ln.get_xdata()) >= 40]
    assert len(profiles) == 3 and max(np.max(np.abs(ln.get_ydata())) for ln in profiles) > 0


def test_a_static_rod_file_draws_its_shape():
    from varint.plotting import fields_figure, monitors_figure

    s = np.linspace(0.0, 1.0, 11)
    r = np.stack([np.sin(s) / 1.0, np.cos(s) - 1.0, 0 * s], axis=1)[None]  # a bent cantilever
    Lam = np.broadcast_to(np.eye(3), (1, 11, 3, 3)).copy()
    mon = {"energy": np.array([-0.0138]), "kinetic_energy": np.zeros(1), "energy_bending_torsion": np.array([0.0072]),
           "energy_load": np.array([-0.021]), "linear_momentum": np.zeros((1, 3)), "angular_momentum_cm": np.zeros((1, 3)),
           "frame_orthogonality": np.array([1e-15]), "newton_iterations": np.zeros(1)}
    run = _run([0.0], mon, {"rod/r": r, "rod/Lambda": Lam}, static=True,
               scene_toml='[tube]\nlength = 1.0\nradius = 0.01\n[rod]\ndimension = 2\n')
    fig = fields_figure(run)
    shapes = [ln for ax in fig.axes for ln in ax.get_lines() if len(ln.get_xdata()) == 11]
    assert shapes and np.allclose(shapes[0].get_ydata(), r[0, :, 1]) and shapes[0].get_marker() == "o"
    fig = monitors_figure(run)
    energy = next(a for a in fig.axes if a.get_ylabel().startswith("energy"))
    assert sorted(t.get_text() for t in energy.get_xticklabels()) == ["bending_torsion", "load", "total"]


# -- rods: deflection and spin ---------------------------------------------------------------------------

def test_rod_deflection_of_a_whirling_shaft_and_its_view():
    from varint.plotting import rod_deflection, rod_view_mode, section_twist

    amp = 1e-4
    t, r, Lam = _shaft(amp=amp)
    along, w, (o, e, e2, e3) = rod_deflection(r)
    s = np.linspace(0.0, 1.0, 21)
    assert np.allclose(along, s[None, :])
    assert np.allclose(w[..., 0], r[..., 1], atol=1e-16) and np.allclose(w[..., 1], r[..., 2], atol=1e-16)
    assert np.max(np.linalg.norm(w, axis=-1)) == pytest.approx(amp)
    assert rod_view_mode(amp, 1.0) == "deflection"  # 1e-4 L: invisible at true scale
    assert rod_view_mode(0.3, 1.0) == "true" and rod_view_mode(3e-14, 1.0) == "rest"
    assert np.allclose(section_twist(Lam), 60.0 * t[:, None])  # the spin, about 60 rad in 1 s, unwrapped

    t, r, Lam = _shaft(amp=0.0)  # spinning rigidly about its axis: a straight line in every snapshot ...
    assert np.max(np.abs(rod_deflection(r)[1])) == 0.0 and rod_view_mode(0.0, 1.0) == "rest"
    assert section_twist(Lam)[-1, 10] == pytest.approx(60.0)  # ... the motion is in the sections


def test_section_twist_is_the_spin_about_the_axis_while_the_axis_swings():
    from varint.lattice.lie import cay
    from varint.plotting import section_twist

    # a section turning about its own axis at 13 rad/s while that axis swings about z at 3 rad/s
    K, dt = 101, 0.01
    t = dt * np.arange(K)
    Rz = np.array([cay(np.array([0.0, 0.0, 2 * np.tan(3.0 * tk / 2)])) for tk in t])
    Lam = (Rz @ _rot_x(13.0 * t))[:, None]
    assert np.allclose(section_twist(Lam)[:, 0], 13.0 * t, atol=1e-9)


def test_the_fields_of_a_whirl_make_the_deflection_and_the_spin_visible():
    from varint.plotting import fields_figure

    amp = 1e-4
    t, r, Lam = _shaft(amp=amp)
    K = len(t)
    mon = {"energy": np.ones(K), "kinetic_energy": np.ones(K), "linear_momentum": np.zeros((K, 3)),
           "angular_momentum_cm": np.zeros((K, 3)), "frame_orthogonality": np.zeros(K), "newton_iterations": np.ones(K)}
    run = _run(t, mon, {"rod/r": r, "rod/Lambda": Lam}, scene_toml='[tube]\nlength = 1.0\nradius = 0.01\n[rod]\ndimension = 3\n')
    fig = fields_figure(run)
    side = [a for a in fig.axes if a.get_title() == "side view"]
    assert len(side) == 2
    for ax in side:  # the deflection fills the axis (on true-scale equal axes it was 1e-4 of it)
        ys = np.concatenate([ln.get_ydata() for ln in ax.get_lines() if len(ln.get_xdata()) == 21])
        lo, hi = ax.get_ylim()
        assert (np.max(ys) - np.min(ys)) > 0.5 * (hi - lo)
        assert "\u00b5m" in ax.get_ylabel()
    spin = next(a for a in fig.axes if "own axis" in a.get_title())
    assert max(np.max(ln.get_ydata()) for ln in spin.get_lines()) == pytest.approx(60.0)

    t, r, Lam = _shaft(amp=0.0)  # the straight spinning shaft: the section mark turns in the end view
    fig = fields_figure(dict(run, fields={"rod/r": r, "rod/Lambda": Lam}))
    end = next(a for a in fig.axes if a.get_title().startswith("end view"))
    marks = [ln for ln in end.get_lines() if len(ln.get_xdata()) == 2]
    tips = {(round(float(ln.get_xdata()[1]), 6), round(float(ln.get_ydata()[1]), 6)) for ln in marks}
    assert len(tips) >= 6  # the mark points in a different direction at each snapshot
    assert any("own axis" in a.get_title() for a in fig.axes)


# -- smoke: real files -----------------------------------------------------------------------------------

def test_plot_run_writes_the_pngs_of_a_tube_run_and_of_a_static_rod_file(tmp_path, capsys):
    from varint.cli import main
    from varint.plotting import plot_run

    d = gas_scene(nodes=17, parcels=16, end=1e-4,
                  perturbation=[{"field": "pressure", "shape": "gaussian", "amplitude": 5e3, "center": 0.5, "width": 0.1}])
    d["output"] = {"every": 2}
    (tmp_path / "tube.toml").write_text(to_toml(d))
    assert main(["run", str(tmp_path / "tube.toml"), "-o", str(tmp_path / "tube.h5"), "-q"]) == 0
    rod = {"title": "small cantilever", "tube": {"length": 1.0, "nodes": 9, "radius": 0.01},
           "rod": {"dimension": 2, "mass_per_length": 0.3, "rotary_inertia": 1e-4, "bending_stiffness": 2.0,
                   "torsional_stiffness": 1.5, "axial_stiffness": 1e3, "shear_stiffness": 8e2,
                   "ends": {"s0": "clamped", "sL": "free"}, "load": {"force": [0.0, -2.0, 0.0]}},
           "time": {"step": 1e-3, "end": 1e-2}}
    (tmp_path / "rod.toml").write_text(to_toml(rod))
    assert main(["static", str(tmp_path / "rod.toml"), "-o", str(tmp_path / "rod_static.h5")]) == 0
    for name in ("tube", "rod_static"):
        paths = plot_run(tmp_path / f"{name}.h5", tmp_path / "png")
        assert sorted(p.name for p in paths) == [f"{name}_fields.png", f"{name}_monitors.png"]
        for p in paths:
            assert p.read_bytes()[:4] == b"\x89PNG" and p.stat().st_size > 10_000


def test_animate_writes_one_gif_frame_per_record_of_a_coupled_run(tmp_path):
    """`varint plot --animate`: the rod's centreline (and the fluid's labels) in 3D, one frame per record; a run
    without a rod gets a note, not an error."""
    import subprocess
    import sys

    from PIL import Image

    from varint.plotting import animate_run, centreline_frames
    from varint.run.io import read_run

    text = (Path(__file__).resolve().parent.parent / "examples" / "water_filled_hose.toml").read_text()
    text = text.replace("end = 2.0", "end = 0.02").replace("every = 10", "every = 4")
    (tmp_path / "hose.toml").write_text(text)
    out = tmp_path / "hose.h5"
    proc = subprocess.run([sys.executable, "-m", "varint", "run", str(tmp_path / "hose.toml"), "-o", str(out), "-q"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    run = read_run(out)
    t, r, axes, X, p = centreline_frames(run)
    assert r.shape == (len(t), 21, 3) and X.shape == (len(t), 21, 3) and p.shape == (len(t), 20) and axes is not None
    gif = animate_run(out, tmp_path / "anim")
    with Image.open(gif) as im:
        assert im.n_frames == len(t)
    d = gas_scene(nodes=9, parcels=8, end=2e-5)
    (tmp_path / "tube.toml").write_text(to_toml(d))
    proc = subprocess.run([sys.executable, "-m", "varint", "run", str(tmp_path / "tube.toml"), "-o", str(tmp_path / "tube.h5"), "-q"],
                          capture_output=True, text=True, timeout=300)
    assert animate_run(tmp_path / "tube.h5") is None
