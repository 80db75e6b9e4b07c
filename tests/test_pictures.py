"""What a new user saw in the pictures (issue 24), each fixed: Sod's maps (records, density, colour scale), the
reference radius, gravity in every view and in the GIF, the GIF's colour bar and whole title, the invariants a
model declares, a spinning shaft that does not whirl, whirl labels in `varint modes`, profiles at chosen times
(`varint plot --at`) with the exact solution.

Figures are built from run dictionaries (as varint.run.io.read_run returns them) and inspected through their
artists; two tests run real scenes through the command line."""

import json
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from helpers import rotations_about_x as _rot_x, run_record as _run
from varint.scene.standard import gas_scene
from varint.scene.text import to_toml

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = sorted((ROOT / "examples").glob("*.toml"))



def _meshes(fig):
    from matplotlib.collections import QuadMesh

    return {ax.get_title(): c for ax in fig.axes if ax.get_label() != "<colorbar>" for c in ax.collections
            if isinstance(c, QuadMesh)}


def _sod_like(K=41, M=200):
    """Two constant states either side of s = 0.5 at t = 0 and a right-moving front: (t, fields)."""
    t = np.linspace(0.0, 0.2, K)
    s = np.linspace(0.0, 1.0, M + 1)
    sc = 0.5 * (s[1:] + s[:-1])
    front = 0.5 + 1.75 * t[:, None]
    p = np.where(sc[None, :] < 0.5 - 1.2 * t[:, None], 1.0, np.where(sc[None, :] < front, 0.3, 0.1))
    rho = np.where(sc[None, :] < 0.5 - 1.2 * t[:, None], 1.0, np.where(sc[None, :] < 0.5 + 0.9 * t[:, None], 0.43,
                                                                       np.where(sc[None, :] < front, 0.27, 0.125)))
    u = np.where((s[None, :] > 0.5 - 1.2 * t[:, None]) & (s[None, :] < front), 0.93, 0.0)
    return t, {"fluid/s": np.broadcast_to(s, (K, M + 1)).copy(), "fluid/pressure": p, "fluid/density": rho,
               "fluid/velocity": u}


# -- Sod: records, density, colour scale -------------------------------------------------------------------------

@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.stem)
def test_every_example_records_enough_to_see_its_motion(path):
    """Sod wrote 11 records (every 20 of 200 steps): a staircase.  Every example now writes at least 50."""
    d = tomllib.loads(path.read_text())
    steps = round(d["time"]["end"] / d["time"]["step"])
    records = steps // d.get("output", {}).get("every", 1) + 1
    assert records >= 50, (path.name, records)


def test_sod_maps_show_the_density_on_a_scale_that_saturates_neither_state():
    from varint.plotting import colour_scale, fields_figure, plateaus

    t, fields = _sod_like()
    scene = (ROOT / "examples" / "sod_shock_tube.toml").read_text()
    fig = fields_figure(_run(t, {}, fields, scene_toml=scene))
    meshes = _meshes(fig)
    titles = " ".join(meshes)
    assert any(k.startswith("density") for k in meshes)  # the contact shows only in the density
    for key in ("pressure", "density"):
        title, m = next((k, v) for k, v in meshes.items() if k.startswith(key))
        y = fields[f"fluid/{key}"]
        assert m.get_cmap().name != "RdBu_r"  # sequential: no centre between the states
        assert m.norm.vmin == pytest.approx(np.min(y)) and m.norm.vmax == pytest.approx(np.max(y))
        assert "median" not in title and "2 states" in title
    assert "median" not in titles
    assert plateaus(fields["fluid/pressure"][0]) == [0.1, 1.0]
    # a pulse on a state at rest has one constant state: a diverging scale about it
    s = np.linspace(0, 1, 201)
    pulse = 101325.0 + 5e3 * np.exp(-((s - 0.5) / 0.05) ** 2)
    assert plateaus(pulse) == [pytest.approx(101325.0)]
    assert colour_scale(np.stack([pulse, pulse]), (101325.0, "fluid.pressure", False)).kind == "diverging"


def test_the_wall_radius_is_measured_from_the_scenes_reference_radius():
    """The traveling shock's page said "R0 = 0.0669 m (median at t = 0)" against tube.radius = 0.05."""
    from varint.plotting import fields_figure

    K, N = 20, 101
    s = np.linspace(0.0, 2.0, N)
    R = np.where(s[None, :] < 1.0 + 0.01 * np.arange(K)[:, None], 0.0669, 0.05)  # behind the shock (more than half)
    scene = (ROOT / "examples" / "rubber_tube_traveling_shock.toml").read_text()
    fig = fields_figure(_run(np.linspace(0, 1e-3, K), {}, {"wall/R": R}, scene_toml=scene))
    (title, m), = _meshes(fig).items()
    assert "R0 = 0.05 m (tube.radius)" in title and "median" not in title
    assert m.get_cmap().name == "RdBu_r" and m.norm.vmax == pytest.approx(-m.norm.vmin)
    assert m.norm.vmax == pytest.approx(16.9)  # (0.0669 - 0.05) m in mm: the scale reaches the state behind


# -- invariants ------------------------------------------------------------------------------------------------------

def _rod_monitors(K):
    rng = np.random.default_rng(3)
    return {"energy": np.full(K, 2.0), "kinetic_energy": np.full(K, 1.0), "energy_gravity": np.full(K, 1.0),
            "mass": np.full(K, 0.3), "linear_momentum": rng.random((K, 3)), "angular_momentum": rng.random((K, 3)),
            "angular_momentum_cm": rng.random((K, 3)), "frame_orthogonality": np.zeros(K), "newton_iterations": np.full(K, 3)}


def test_a_clamped_hose_shows_only_the_invariants_its_model_declares():
    from varint.plotting import declared_invariants, monitor_panels, monitors_figure

    text = (ROOT / "examples" / "water_filled_hose.toml").read_text()
    K = 12
    run = _run(np.linspace(0, 1, K), _rod_monitors(K), {}, scene_toml=text)
    inv = declared_invariants(run)
    assert inv == ["energy", "mass", "parcel_volume"]
    labels = [p.label for p in monitor_panels(run["monitors"], inv)]
    assert not any("momentum" in lab for lab in labels), labels  # the clamp and gravity break both momenta
    assert any(lab.startswith("relative mass error") for lab in labels)
    fig = monitors_figure(run, inv)
    assert "invariants the model declares: energy, mass, parcel_volume" in fig._suptitle.get_text()
    assert not any("momentum" in ax.get_ylabel() for ax in fig.axes)
    # the default (no scene: every momentum) is unchanged
    assert any("change of linear momentum" in p.label for p in monitor_panels(run["monitors"]))


def test_a_shaft_on_bearings_shows_its_angular_momentum_about_the_bearing_axis():
    from varint.plotting import monitor_panels

    K = 10
    mon = _rod_monitors(K)
    a, e = np.array([0.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0])
    mon["angular_momentum"] = np.stack([np.full(K, 0.5), np.linspace(0, 1, K), np.linspace(0, 2, K)], axis=1)
    panels = monitor_panels(mon, ["energy", "angular_momentum_about_the_bearing_axis"], {"axis": (a, e)})
    (p,) = [p for p in panels if "momentum" in p.label]
    assert "about the bearing axis" in p.label
    assert np.max(p.curves[0][1]) == 0.0  # J_x is kept; the transverse components that change are not drawn
    g = np.array([0.0, -9.81, 0.0])
    panels = monitor_panels(mon, ["energy", "linear_momentum_transverse_to_gravity", "angular_momentum_along_gravity"],
                            {"gravity": g})
    labels = [p.label for p in panels if "momentum" in p.label]
    assert labels == ["change of linear momentum across gravity [kg m/s]",
                      "change of angular momentum along gravity [kg m2/s]"]


# -- gravity, the GIF --------------------------------------------------------------------------------------------------

def _hose_run(K=9, n=11, M=10, gravity=(9.81, 0.0, 0.0), title="A garden hose " + "whipping " * 12 + "END"):
    t = np.linspace(0.0, 0.1, K)
    s = np.linspace(0.0, 0.5, n)
    r = np.zeros((K, n, 3))
    r[..., 0] = s
    r[..., 1] = 0.05 * np.sin(3 * t)[:, None] * s[None, :] ** 2
    Lam = np.broadcast_to(np.eye(3), (K, n, 3, 3)).copy()
    X = np.zeros((K, M + 1, 3))
    X[..., 0] = np.linspace(0.0, 0.5, M + 1)
    p = 1e5 + 1e3 * np.arange(M)[None, :] * np.ones((K, 1))
    scene = to_toml({"title": title, "tube": {"length": 0.5, "nodes": n, "radius": 0.008}, "rod": {"dimension": 3},
                     "environment": {"gravity": list(gravity)}})
    fields = {"rod/r": r, "rod/Lambda": Lam, "fluid/position": X, "fluid/pressure": p}
    return _run(t, {}, fields, scene_toml=scene, title=title)


def test_gravity_is_drawn_in_every_view_of_a_rod():
    from varint.plotting import fields_figure, gravity_in_view

    ex, ey, ez = np.eye(3)
    assert gravity_in_view((9.81, 0, 0), ex, ey)[:2] == (1.0, 0.0)  # down the page's x axis
    assert gravity_in_view((0, -9.81, 0), ex, ey)[:2] == (0.0, -1.0)
    dx, dy, normal = gravity_in_view((9.81, 0, 0), ey, ez)  # along the line of sight of an end view
    assert (dx, dy) == (0.0, 0.0) and normal == pytest.approx(1.0)
    assert gravity_in_view((0, 0, 0), ex, ey) is None

    run = _hose_run()
    fig = fields_figure(run)
    views = [ax for ax in fig.axes if "view" in ax.get_title()]
    assert len(views) == 3
    for ax in views:
        marks = [c for c in ax.get_children() if c.get_gid() == "gravity"]
        assert len(marks) == 1 and marks[0].get_text().startswith("g"), ax.get_title()
    side = next(ax for ax in views if ax.get_title() == "side view")
    (arrow,) = [c for c in side.get_children() if c.get_gid() == "gravity"]
    assert arrow.xy[0] > arrow.xyann[0] and arrow.xy[1] == pytest.approx(arrow.xyann[1])  # g along +x
    no_g = fields_figure(_hose_run(gravity=(0.0, 0.0, 0.0)))
    assert not [c for ax in no_g.axes for c in ax.get_children() if c.get_gid() == "gravity"]


def test_the_animation_has_a_pressure_colour_bar_gravity_and_its_whole_title():
    from varint.plotting import animation_figure

    run = _hose_run()
    fig, draw, frames = animation_figure(run)
    assert list(frames) == list(range(9))
    draw(frames[-1])
    bars = [ax for ax in fig.axes if ax.get_label() == "<colorbar>"]
    assert len(bars) == 1 and bars[0].get_ylabel().startswith("p [Pa]")
    lo, hi = bars[0].get_ylim()
    assert lo == pytest.approx(1e5) and hi == pytest.approx(1.09e5)
    ax3 = fig.axes[0]
    title = ax3.get_title()
    assert " ".join(title.split()).startswith(run["attrs"]["title"].strip()) and "END" in title  # wrapped, not cut
    assert "t = 0.1 s" in title
    assert any(c.get_gid() == "gravity" for c in ax3.get_children())


# -- the spinning shaft ------------------------------------------------------------------------------------------------


def _shaft(amp, whirl, spin=60.0, K=81, n=21):
    t = np.linspace(0.0, 1.0, K)
    s = np.linspace(0.0, 1.0, n)
    r = np.zeros((K, n, 3))
    r[..., 0] = s
    r[..., 1] = amp * np.sin(np.pi * s)[None, :] * np.cos(whirl * t)[:, None]
    r[..., 2] = amp * np.sin(np.pi * s)[None, :] * np.sin(whirl * t)[:, None]
    Lam = np.broadcast_to(_rot_x(spin * t)[:, None], (K, n, 3, 3)).copy()
    mon = {"energy": np.ones(K), "kinetic_energy": np.ones(K), "frame_orthogonality": np.zeros(K)}
    return _run(t, mon, {"rod/r": r, "rod/Lambda": Lam},
                scene_toml='title = "shaft"\n[tube]\nlength = 1.0\nradius = 0.01\n[rod]\ndimension = 3\n')


def test_a_shaft_in_steady_rotation_says_why_its_centreline_stays_straight():
    from varint.plotting import fields_figure

    fig = fields_figure(_shaft(0.0, 0.0))
    text = " ".join(fig.subfigs[0]._suptitle.get_text().split())  # (wrapped to the figure's width)
    assert "steady rotation about its own axis" in text and "rod.perturbation" in text


def test_a_synchronous_whirl_stands_still_in_the_frame_spinning_with_the_shaft():
    from varint.plotting import fields_figure

    fig = fields_figure(_shaft(1e-4, 60.0))  # whirling at the spin rate: a bent shaft turning rigidly
    ax = next(a for a in fig.axes if "frame spinning with the shaft" in a.get_title())
    path = next(ln for ln in ax.get_lines() if len(ln.get_xdata()) == 81)
    pts = np.stack([path.get_xdata(), path.get_ydata()], axis=1)
    assert np.max(np.abs(pts - pts[0])) < 1e-6 * 100  # one point (in um): the whirl does not move there
    lab = next(a for a in fig.axes if a.get_title().startswith("end view, node") and "spinning" not in a.get_title())
    path = next(ln for ln in lab.get_lines() if len(ln.get_xdata()) == 81)
    assert np.ptp(path.get_xdata()) > 150  # in the lab it goes round (um)


def test_modes_label_forward_and_backward_whirl(tmp_path, capsys):
    """The spinning shaft's first bending pair (docs/validation.md, 'Spinning shaft'): forward 27.02 rad/s and
    backward 23.21 rad/s in the lab, 32.98 and 83.21 seen from the spinning frame."""
    from varint.cli import main

    text = (ROOT / "examples" / "spinning_shaft.toml").read_text().replace("nodes = 41", "nodes = 21")
    (tmp_path / "shaft.toml").write_text(text)
    assert main(["modes", str(tmp_path / "shaft.toml"), "-n", "4", "--json"]) == 0
    modes = json.loads(capsys.readouterr().out)["modes"]
    whirls = [(m["whirl"], m["frequency"], m["lab_frequency"]) for m in modes if m["whirl"]]
    fw = next(w for w in whirls if w[0] == "forward")
    bw = next(w for w in whirls if w[0] == "backward")
    assert fw[1] == pytest.approx(32.98, rel=2e-3) and fw[2] == pytest.approx(27.02, rel=2e-3)
    assert bw[1] == pytest.approx(83.21, rel=2e-3) and bw[2] == pytest.approx(23.21, rel=2e-3)
    assert main(["modes", str(tmp_path / "shaft.toml"), "-n", "4"]) == 0
    out = capsys.readouterr().out
    assert "forward whirl" in out and "backward whirl" in out and "rad/s in the lab" in out


# -- profiles at chosen times --------------------------------------------------------------------------------------

def test_exact_profiles_of_the_examples():
    from varint.plotting import exact_profiles
    from varint.scene.schema import load_scene

    sod = exact_profiles(load_scene(ROOT / "examples" / "sod_shock_tube.toml"))
    assert sod is not None and "Riemann" in sod.name
    s = np.array([0.1, 0.49, 0.51, 0.9])
    f0 = sod.fields(s, 0.0)
    assert np.allclose(f0["pressure"], [1, 1, 0.1, 0.1]) and np.allclose(f0["density"], [1, 1, 0.125, 0.125])
    f = sod.fields(np.array([0.6, 0.8]), 0.2)  # Toro's star region: p* = 0.30313, u* = 0.92745
    assert f["pressure"] == pytest.approx([0.30313, 0.30313], rel=1e-4) and f["velocity"][0] == pytest.approx(0.92745, rel=1e-4)
    assert 0.2 < sod.valid_until < 0.3  # the shock (1.752 m/s) reaches s = 1 at 0.285 s
    ts = exact_profiles(load_scene(ROOT / "examples" / "rubber_tube_traveling_shock.toml"))
    assert ts is not None and "traveling shock" in ts.name
    ahead = ts.fields(np.array([1.9]), 0.0)
    assert ahead["R"][0] == pytest.approx(0.05, rel=1e-5) and ahead["pressure"][0] == pytest.approx(101325.0, rel=1e-5)
    moved = ts.fields(np.array([1.0 + 447.0 * 1e-3 - 1e-6, 1.0 + 447.0 * 1e-3 + 1e-6]), 1e-3)
    assert moved["pressure"][0] > 1.2 * moved["pressure"][1]  # the jump has moved with the wave
    for name in ("rubber_tube_pulse", "water_filled_hose", "open_pipe_gas"):
        assert exact_profiles(load_scene(ROOT / "examples" / f"{name}.toml")) is None


def test_profiles_at_chosen_times_use_the_nearest_records_and_draw_the_exact_solution():
    from varint.plotting import nearest_records, profiles_figure

    t, fields = _sod_like()
    scene = (ROOT / "examples" / "sod_shock_tube.toml").read_text()
    run = _run(t, {}, fields, scene_toml=scene)
    assert nearest_records(t, [0.0, 0.101, 0.2]) == [0, 20, 40]
    fig, ks = profiles_figure(run, [0.0, 0.101, 0.2])
    assert ks == [0, 20, 40]
    panels = {ax.get_title(): ax for ax in fig.axes if ax.get_visible()}
    assert set(panels) == {"pressure", "density", "velocity"}  # a rigid tube writes no radius
    ax = panels["density"]
    labels = [ln.get_label() for ln in ax.get_lines()]
    assert "t = 0.1 s (asked 0.101 s)" in labels and "exact" in labels
    drawn = next(ln for ln in ax.get_lines() if ln.get_label() == "t = 0.1 s (asked 0.101 s)")
    assert np.allclose(drawn.get_ydata(), fields["fluid/density"][20])
    assert "Riemann problem" in fig._suptitle.get_text()
    assert profiles_figure(_run(t, {}, {"rod/r": np.zeros((len(t), 3, 3))}), [0.1])[0] is None


def test_plot_at_writes_the_profiles_of_a_run(tmp_path, capsys):
    from varint.cli import main

    d = gas_scene(nodes=9, parcels=8, end=4e-5, h=1e-5,
                  perturbation=[{"field": "pressure", "shape": "gaussian", "amplitude": 5e3, "center": 0.5, "width": 0.1}])
    (tmp_path / "tube.toml").write_text(to_toml(d))
    assert main(["run", str(tmp_path / "tube.toml"), "-o", str(tmp_path / "tube.h5"), "-q"]) == 0
    capsys.readouterr()
    assert main(["plot", str(tmp_path / "tube.h5"), "--at", "0,2.2e-5", "-d", str(tmp_path / "png")]) == 0
    out = capsys.readouterr().out
    assert "tube_profiles.png: profiles at t = 0 s, 2e-05 s (nearest to 2.2e-05)" in out
    png = tmp_path / "png" / "tube_profiles.png"
    assert png.read_bytes()[:4] == b"\x89PNG"
    assert main(["plot", str(tmp_path / "tube.h5"), "--at", "soon"]) == 2
    assert "--at 'soon'" in capsys.readouterr().err
    assert math.isfinite(png.stat().st_size)
