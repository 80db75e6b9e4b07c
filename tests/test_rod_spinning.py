"""Modes of a rod in steady rotation: the gyroscopic matrix, against the theory of spinning shafts."""

import json
import math

import numpy as np
import pytest

from varint import Simulation, build_model, parse_scene
from varint.analysis.linear import gyroscopic_modes_of
from varint.errors import SolverError
from varint.lattice.lie import cay, dcay
from varint.model.statics import rotating_frame_kinetics
from varint.analysis.rod_modes import rod_modes

from varint.analysis.signals import nearest
from varint.scene.standard import (BLADE_SECTION as BLADE, BLADE_SPIN, ROD_SECTION as SECTION, SHAFT_SECTION as SHAFT,
                                   SHAFT_SPIN_RATE as SPIN_RATE, blade_scene, rod_scene, shaft_scene, solid_section)
from varint.scene.standard import shaft_whirl as whirl
from varint.scene.text import to_toml

from _runs import blade_lattice_flap, blade_time_domain_flap, shaft_time_domain_whirl

# the shaft (varint.scene.standard.shaft_scene): a thick shaft (radius of gyration 5.8 cm on 1 m) so that the
# gyroscopic splitting is large; axial and torsional modes placed above the first three bending pairs; whirl: the
# continuum theory's forward and backward whirl of bending mode n (seen from the ground)


def test_gyroscopic_modes_of_known_systems():
    """A particle on an isotropic spring seen from a frame turning at W: frequencies |sqrt(k) -+ W|."""
    k, W = 9.0, 1.0
    K = (k - W * W) * np.eye(2)
    G = 2 * W * np.array([[0.0, -1.0], [1.0, 0.0]])
    f = [m["frequency"] for m in gyroscopic_modes_of(K, G, np.ones(2), 2)]
    assert f == pytest.approx([math.sqrt(k) - W, math.sqrt(k) + W], rel=1e-12)
    # without a spring and beyond it: gyroscopic stabilisation keeps both frequencies real...
    f = gyroscopic_modes_of(-W * W * np.eye(2), G, np.ones(2), 2)
    assert [m["growth_rate"] for m in f] == [0.0, 0.0]
    # ...a plain negative stiffness is a growing real pair, listed first
    res = gyroscopic_modes_of(np.diag([-4.0, 1.0]), np.zeros((2, 2)), np.ones(2), 2)
    assert res[0] == {"frequency": 0.0, "growth_rate": pytest.approx(2.0)} and res[1]["frequency"] == pytest.approx(1.0)
    # flutter: unequal stiffnesses under a weak gyroscopic coupling with a negative one (a quadruple +-a +-iw)
    res = gyroscopic_modes_of(np.diag([-1.0, -2.0]), 0.5 * np.array([[0.0, -1.0], [1.0, 0.0]]), np.ones(2), 2)
    lam = np.linalg.eigvals(np.block([[np.zeros((2, 2)), np.eye(2)], [-np.diag([-1.0, -2.0]), -0.5 * np.array([[0.0, -1.0], [1.0, 0.0]])]]))
    assert sorted(m["growth_rate"] for m in res) == pytest.approx(sorted(abs(lam.real))[::2], rel=1e-10)


def test_rotating_frame_kinetics_blocks_match_finite_differences():
    """b, C, H are the first and second derivatives of the exact kinetic energy in the spinning frame."""
    model = build_model(rod_scene(nodes=5, initial={"curvature": [0.3, -0.5, 0.8]}))
    Omega = np.array([1.3, -0.7, 2.1])
    Lam, r = model.rod.Lam0, model.rod.r0
    b, C, H = rotating_frame_kinetics(model, Omega, Lam, r)
    m = model.rod.section.rhoA * model.rod.w
    rc = (m[:, None] * r).sum(0) / m.sum()
    j = 2
    inertia = model.rod.section.inertia * model.rod.w[j]

    def T(x):  # x = (dr, sigma, dr', sigma') of node j
        dr, sig, drd, sigd = x[:3], x[3:6], x[6:9], x[9:]
        v = np.cross(Omega, r[j] - rc + dr) + drd
        w = cay(sig).T @ Lam[j].T @ Omega + dcay(-sig) @ sigd
        return 0.5 * m[j] * v @ v + 0.5 * w @ (inertia * w)

    x0 = np.zeros(12)
    eps = 1e-4
    E = np.eye(12) * eps
    grad = np.array([(T(x0 + e) - T(x0 - e)) / (2 * eps) for e in E])
    hess = np.array([[(T(x0 + a + c) - T(x0 + a - c) - T(x0 - a + c) + T(x0 - a - c)) / (4 * eps * eps) for c in E] for a in E])
    scale = np.max(np.abs(hess))
    assert np.max(np.abs(grad[:6] - b[j])) < 1e-8 * np.max(np.abs(grad))
    assert np.max(np.abs(hess[6:, :6] - C[j])) < 1e-6 * scale
    assert np.max(np.abs(hess[:6, :6] - H[j])) < 1e-6 * scale
    assert np.max(np.abs(hess[6:, 6:] - np.diag(np.r_[m[j] * np.ones(3), inertia]))) < 1e-6 * scale


def _rotating_frame_prediction(count=3):
    """Seen from the frame spinning at W: forward whirl at |w_f - W|, backward at w_b + W."""
    out = []
    for n in range(1, count + 1):
        wf, wb = whirl(n)
        out += [abs(wf - SPIN_RATE), wb + SPIN_RATE]
    return np.sort(out)


def test_spinning_shaft_whirl_against_timoshenko_theory_order_two():
    """Pinned-pinned shaft at 2.3x its first critical speed: the three lowest forward/backward whirl pairs."""
    pred = _rotating_frame_prediction()
    errs = []
    for nodes in (21, 41, 81):
        # sparse shift-invert: the lowest modes only, and no dense O(n^3) eig (sparse = dense is tested below)
        f = [m["frequency"] for m in rod_modes(build_model(shaft_scene(nodes)), count=12, method="sparse")]
        errs.append(np.abs(nearest(f, pred) / pred - 1))
    errs = np.array(errs)
    assert np.max(errs[-1]) < 1e-3, errs[-1]
    order = np.log2(errs[1] / errs[2])
    big = errs[1] > 1e-5  # order measurable where the error is not at the level of the eigen-solver
    assert np.all(np.abs(order[big] - 2.0) < 0.15), order
    # the test can fail: without the gyroscopic matrix the spin would leave every frequency at its
    # non-spinning value, 9-27 % away from the prediction
    still = np.array([m["frequency"] for m in rod_modes(build_model(shaft_scene(41, spin=0.0)), count=12)])
    bending = [(whirl(n, 0.0)[0]) for n in (1, 2, 3)]
    assert np.min(np.abs(np.subtract.outer(pred, bending)) / pred[:, None]) > 0.05
    assert nearest(still, bending) == pytest.approx(bending, rel=2e-3)


def test_spinning_shaft_time_domain_whirls_at_the_predicted_frequencies():
    """Released from a small planar bend, the spinning shaft's midpoint traces a forward and a backward
    whirl: the time-domain integrator and the continuum theory agree on both frequencies (3 s, ~11
    periods of the backward whirl; the modes of the same 20-element lattice are within 1.2e-3)."""
    w1, w2 = shaft_time_domain_whirl()
    wf, wb = whirl(1)
    assert w1 == pytest.approx(wf, rel=2e-3) and w2 == pytest.approx(wb, rel=2e-3), (w1, w2, wf, wb)
    assert abs(wf - wb) > 0.1 * whirl(1, 0.0)[0]  # a real splitting, resolved


def test_modes_cli_reports_the_spinning_frame(tmp_path, capsys):
    from varint.cli import main

    d = {"title": "shaft", "tube": {"length": 1.0, "nodes": 41, "radius": 0.01},
         "rod": dict(SHAFT, ends={"s0": "pinned", "sL": "pinned"}, initial={"angular_velocity": [SPIN_RATE, 0.0, 0.0]}),
         "time": {"step": 1e-3, "end": 1.0}}
    f = tmp_path / "shaft.toml"
    f.write_text(to_toml(d))
    assert main(["modes", str(f), "--json", "-n", "3"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["frame"]["angular_velocity"] == [SPIN_RATE, 0.0, 0.0]
    assert [m["frequency"] for m in out["modes"]][1:] == pytest.approx(_rotating_frame_prediction()[:2], rel=3e-3)


@pytest.mark.parametrize("rod, words", [
    # end over end about a transverse axis: the centrifugal pull is not balanced by the unstretched rod
    (dict(SECTION, ends={"s0": "free", "sL": "free"}, initial={"angular_velocity": [0.0, 0.0, 3.0]}), "steady rotation"),
    (dict(SECTION, ends={"s0": "clamped", "sL": "free"}, initial={"angular_velocity": [3.0, 0.0, 0.0]}), "rod.ends.s0"),
    (dict(SECTION, ends={"s0": "pinned", "sL": "free"}, initial={"velocity": [0.0, 1.0, 0.0]}), "rod.initial.velocity"),
])
def test_modes_of_a_rod_not_in_steady_motion_are_refused(tmp_path, capsys, rod, words):
    from varint.cli import main

    d = {"title": "spin", "tube": {"length": 1.0, "nodes": 11, "radius": 0.01}, "rod": rod, "time": {"step": 1e-3, "end": 1.0}}
    f = tmp_path / "spin.toml"
    f.write_text(to_toml(d))
    assert main(["modes", str(f)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0], err


def test_free_rod_spinning_about_its_axis_is_steady():
    """A free straight rod spinning about its own axis is a relative equilibrium: modes exist, none grows."""
    model = build_model(rod_scene(nodes=11, section=SHAFT, initial={"angular_velocity": [40.0, 0.0, 0.0]}))
    res = rod_modes(model, count=30)
    assert all(m["growth_rate"] < 1e-6 * max(x["frequency"] for x in res) for m in res)
    with pytest.raises(SolverError, match="steady rotation"):
        rod_modes(build_model(rod_scene(nodes=11, section=SHAFT, initial={"angular_velocity": [0.0, 40.0, 0.0]})))


# -- a free rod spun end over end: the steady rotation balances centrifugal tension (a rotor blade)

# (varint.scene.standard.blade_scene: slender, stiff in shear and stretch, so that the Euler-Bernoulli rotating beam
# applies, to ~1e-5)


def test_steady_rotation_stretches_the_rod_as_the_centrifugal_tension_says():
    """The spinning bar: EA u'' + rhoA W^2 (x + u) = 0, u(0) = 0, u'(l) = 0 (x from the centre) gives
    the elongation 2 (tan(k l)/k - l), k^2 = rhoA W^2 / EA (to first order rhoA W^2 (2 l^3/3) / EA,
    which is 1.2e-4 short: the centrifugal pull grows with the stretch).  Order 2 in ds."""
    from varint.model.statics import static_equilibrium

    W, l = BLADE_SPIN[2], 0.5
    k = math.sqrt(BLADE["mass_per_length"] * W * W / BLADE["axial_stiffness"])
    exact = 2 * (math.tan(k * l) / k - l)
    errs = []
    for nodes in (21, 41, 81):
        model = build_model(blade_scene(nodes))
        Lam, r, _ = static_equilibrium(model, spin=BLADE_SPIN)
        errs.append(abs(np.linalg.norm(r[-1] - r[0]) - 1.0 - exact) / exact)
        m = model.rod.section.rhoA * model.rod.w
        assert np.allclose((m[:, None] * r).sum(0) / m.sum(), [0.5, 0.0, 0.0], atol=1e-12)  # the centre stays on the axis
    assert errs[-1] < 2e-3, errs
    assert np.log2(errs[1] / errs[2]) == pytest.approx(2.0, abs=0.2), errs


@pytest.mark.slow  # 0.5-1.7 min: the slow tier (tests/conftest.py; CI runs it)
def test_spinning_free_rod_flap_and_lag_against_the_rotating_beam():
    """Modes about the steady rotation: out-of-plane (flap) frequencies stiffened by the centrifugal
    tension, against shooting on the rotating Euler-Bernoulli beam; in-plane (lag) ones obey
    w_lag^2 = w_flap^2 - W^2; the rigid tilt sits at W.  Without the rotation terms the lowest flap
    frequency would be the free-free 57.8 rad/s instead of 67.5."""
    from varint.exact.beams import spinning_free_rod_flap
    from varint.model.statics import static_equilibrium

    W = BLADE_SPIN[2]
    flap = spinning_free_rod_flap(BLADE["bending_stiffness"], BLADE["mass_per_length"], 1.0, W, 400.0)
    assert flap[0] == pytest.approx(W, rel=1e-9)  # the shooting's own check: the rigid tilt
    flap = np.array(flap[1:4])
    lag = np.sqrt(flap ** 2 - W * W)
    errs = []
    for nodes in (41, 81):
        model = build_model(blade_scene(nodes))
        Lam, r, _ = static_equilibrium(model, spin=BLADE_SPIN)
        f = np.array([m["frequency"] for m in rod_modes(model, count=16, Lam=Lam, r=r, method="sparse")])
        # seen from the spinning frame: the rigid tilt at W, and the in-plane drift of the free body, a
        # defective (Jordan) pair at W that eigen-solvers resolve only to ~sqrt(eps |A|) (dense: 1.2 % /
        # 2.8 % at 40 / 80 elements, independent of the Hessian's difference step: checked); the pair
        # also blurs the tilt next to it (to ~3e-6 here)
        assert np.sum(np.abs(f / W - 1) < 1e-4) >= 1 and np.sum(np.abs(f / W - 1) < 5e-2) == 3, f[:8]
        errs.append(np.concatenate([nearest(f, flap) / flap - 1, nearest(f, lag) / lag - 1]))
    errs = np.abs(errs)
    assert np.max(errs[-1]) < 1e-3, errs  # measured 4.9e-4 .. 6.9e-4 at 80 elements
    order = np.log2(errs[0] / errs[1])[[0, 1, 3, 4]]  # modes 1-2, flap and lag
    assert np.all(np.abs(order - 2.0) < 0.2), order


def test_a_run_started_in_the_steady_rotation_stays_in_it():
    """The time-domain rod released in its steady rotation keeps its shape over a full turn: the elastic
    energy of the centrifugal stretch varies by O((W h)^2) only (the discrete flow's own steady
    rotation differs from the continuous one at that order)."""
    from varint.model.statics import static_equilibrium

    wobble = []
    for h in (2e-3, 1e-3):
        model = build_model(blade_scene(21, h=h))
        Lam, r, _ = static_equilibrium(model, spin=BLADE_SPIN)
        model.rod.set_configuration(Lam, r)
        sim = Simulation(model)
        e0 = sim.monitors()["energy_stretch_shear"]
        assert e0 > 0
        worst = 0.0
        for _ in range(int(round(2 * math.pi / BLADE_SPIN[2] / h))):
            sim.step()
            worst = max(worst, abs(sim.monitors()["energy_stretch_shear"] / e0 - 1))
        wobble.append(worst)
        # and it did turn: a full revolution brings the tip back to its start
        assert np.linalg.norm(sim.fields()["rod/r"][-1] - r[-1]) < 0.01
    assert wobble[0] < 2e-3 and wobble[0] / wobble[1] == pytest.approx(4.0, rel=0.15), wobble  # (W h)^2 = 1.6e-3


@pytest.mark.slow  # 0.4-0.8 min: the slow tier (tests/conftest.py; CI runs it)
def test_cli_static_and_modes_of_a_spinning_rod(tmp_path, capsys):
    """`varint static` writes the steady rotation (with its momenta); `modes --about static` uses it."""
    import h5py

    from varint.exact.beams import spinning_free_rod_flap
    from varint.cli import main
    from varint.run.io import read_run

    d = {"title": "blade", "tube": {"length": 1.0, "nodes": 41, "radius": 0.01},
         "rod": dict(BLADE, ends={"s0": "free", "sL": "free"}, initial={"angular_velocity": list(BLADE_SPIN)}),
         "time": {"step": 1e-3, "end": 1.0}}
    f = tmp_path / "blade.toml"
    f.write_text(to_toml(d))
    out = tmp_path / "steady.h5"
    assert main(["static", str(f), "-o", str(out)]) == 0
    assert "steady rotation" in capsys.readouterr().out
    run = read_run(out)
    r = run["fields"]["rod/r"][0]
    assert np.linalg.norm(r[-1] - r[0]) > 1.0 + 1e-5  # stretched by the centrifugal tension
    with h5py.File(out, "r") as h:
        assert list(h.attrs["steady_rotation"]) == list(BLADE_SPIN)
        assert h.attrs["turned_deg"] < 1e-6  # spun about a principal axis: the rod keeps its orientation
    # the momenta are those of the rigid rotation of the lumped masses (and section inertias)
    model = build_model(parse_scene(f.read_text()))
    m = model.rod.section.rhoA * model.rod.w
    rc = (m[:, None] * r).sum(0) / m.sum()
    J_rigid = BLADE_SPIN[2] * (np.sum(m * np.sum((r - rc)[:, :2] ** 2, axis=1)) + np.sum(model.rod.w) * BLADE["rotary_inertia"])
    assert run["monitors"]["angular_momentum"][0] == pytest.approx([0.0, 0.0, J_rigid], rel=1e-12, abs=1e-14)
    assert main(["modes", str(f), "--about", "static", "--json", "-n", "8"]) == 0
    modes = json.loads(capsys.readouterr().out)["modes"]
    flap1 = spinning_free_rod_flap(BLADE["bending_stiffness"], BLADE["mass_per_length"], 1.0, BLADE_SPIN[2], 100.0)[1]
    assert modes[7]["frequency"] == pytest.approx(flap1, rel=3e-3)


def test_scene_can_start_from_the_steady_rotation(tmp_path):
    """rod.initial.shape = "steady_rotation": the run starts stretched and stays so; the plain start
    (unstretched, spinning) rings with the stretch instead."""
    from varint import run_scene
    from varint.run.io import read_run

    swings = {}
    for shape in ("steady_rotation", "given"):
        scene = rod_scene(nodes=21, section=BLADE, h=1e-3, end=0.1,
                          initial={"angular_velocity": list(BLADE_SPIN), "shape": shape})
        run_scene(scene, str(tmp_path / f"{shape}.h5"), progress=False)
        e = read_run(tmp_path / f"{shape}.h5")["monitors"]["energy_stretch_shear"]
        swings[shape] = (np.max(e) - np.min(e)) / np.max(e)
    assert swings["steady_rotation"] < 1e-3 and swings["given"] > 0.5, swings


@pytest.mark.parametrize("case", ["cantilever", "free", "spinning_shaft"])
def test_sparse_shift_invert_modes_equal_the_dense_ones(case):
    """rod_modes(method="sparse") (eigsh / eigs with shift-invert, used above 1500 unknowns) returns the
    dense solver's lowest modes; rigid modes (free rod, the shaft's spin) come out as zeros in both."""

    model = {"cantilever": lambda: build_model(rod_scene(nodes=41, section=solid_section(), ends=("clamped", "free"))),
             "free": lambda: build_model(rod_scene(nodes=31)),
             "spinning_shaft": lambda: build_model(shaft_scene(41))}[case]()
    dense = rod_modes(model, count=10, method="dense")
    sparse = rod_modes(model, count=10, method="sparse")
    fd, fs = np.array([m["frequency"] for m in dense]), np.array([m["frequency"] for m in sparse])
    elastic = fd > 1e-3 * fd.max()  # rigid modes of the free rod sit at ~1e-5 (the eigen-solvers' round-off)
    assert np.allclose(fs[elastic], fd[elastic], rtol=1e-9), (fd, fs)
    assert np.all(fs[~elastic] < 1e-4 * fd[elastic][0])
    assert all(m["growth_rate"] == 0.0 for m in sparse)


@pytest.mark.slow  # 0.3-0.4 min: the slow tier (tests/conftest.py; CI runs it)
def test_modes_of_a_thousand_element_rod():
    """Above 1500 unknowns rod_modes goes sparse: 1000 elements (6000 unknowns) against Timoshenko."""
    from varint.exact.beams import timoshenko_cantilever

    sec = solid_section()
    tim = timoshenko_cantilever(sec["bending_stiffness"], sec["shear_stiffness"], sec["mass_per_length"],
                                sec["rotary_inertia"], 1.0)
    model = build_model(rod_scene(nodes=1001, section=sec, ends=("clamped", "free")))
    f = np.array([m["frequency"] for m in rod_modes(model, count=6)])[::2]  # each bending frequency twice (3D)
    assert f == pytest.approx(tim[:3], rel=2e-6)  # lattice error at 1000 elements: ~2.6e-7


def test_steady_rotation_of_a_rod_spun_about_no_principal_axis_is_the_nearest_one():
    """The tumbling example's straight rod (along x) spun about (13, 40, -27): the nearest steady
    rotation is end over end, the chord turned by asin(13/|W|) = 15.1 degrees into the plane normal
    to the spin (plain Newton had wandered to the chord along the spin axis, 75 degrees away)."""
    from pathlib import Path

    from varint.model.statics import static_equilibrium

    model = build_model(parse_scene((Path(__file__).resolve().parent.parent / "examples" / "tumbling_rod.toml").read_text()))
    W = model.rod.spin
    Lam, r, info = static_equilibrium(model, spin=W)
    chord = r[-1] - r[0]
    assert abs(np.dot(chord, W)) < 1e-9 * np.linalg.norm(chord) * np.linalg.norm(W)
    assert info["turned_deg"] == pytest.approx(math.degrees(math.asin(W[0] / np.linalg.norm(W))), abs=0.05)


def test_spinning_free_rod_flaps_at_the_stiffened_frequency_in_the_time_domain():
    """Released from its steady rotation with a small out-of-plane bend, the spun rod's tip flaps at the
    centrifugally stiffened frequency (67.4 rad/s for this lattice, 57.8 without spin): the time-domain
    frequency converges to the modes' at order 2 in h."""
    lattice = blade_lattice_flap()
    errs = [blade_time_domain_flap(h) / lattice - 1 for h in (2e-3, 1e-3)]
    assert abs(lattice / 67.5013 - 1) < 2e-3  # the lattice's mode against the rotating beam (test above)
    assert abs(errs[1]) < 5e-4 and errs[0] / errs[1] == pytest.approx(4.0, rel=0.25), errs
