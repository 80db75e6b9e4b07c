"""The Cayley-map rod: action gradient with Lie-group variations, conservation, loads, waves, modes, statics."""

import math
from pathlib import Path

import numpy as np
import pytest

from varint import Simulation, build_model
from varint.lattice.lie import cay, cay_inv
from varint.model.statics import lumped_mass, static_equilibrium
from varint.analysis.rod_modes import rod_modes

from varint.scene.standard import (ROD_SECTION as SECTION, ROD_SPIN as SPIN, ROD_STIFF_SECTION as STIFF, rod_scene,
                                   solid_section, tumbling_scene)
from varint.scene.text import to_toml


def _random_levels(model, rng, amp=0.05):  # noqa: D401
    """Three nearby lattice configurations (Lambda, r) around the initial one."""
    out = []
    for _ in range(3):
        Lam = model.rod.Lam0 @ cay(amp * rng.standard_normal((model.N + 1, 3)))
        r = model.rod.r0 + amp * model.ds * rng.standard_normal((model.N + 1, 3))
        out.append((Lam, r))
    return out


@pytest.mark.parametrize("measure", ["paper", "reference"])
@pytest.mark.parametrize("extras", ["plain", "gravity+force"])
def test_step_residual_is_gradient_of_action_with_lie_variations(measure, extras):
    kw = {"gravity": [0.3, -9.81, 0.5], "load": {"force": [1.0, -2.0, 0.5]}} if extras != "plain" else {}
    model = build_model(rod_scene(measure=measure, ends=("clamped", "free"), **kw))
    h = 1e-3
    rng = np.random.default_rng(3)
    (L0, r0), (L1, r1), (L2, r2) = _random_levels(model, rng)

    def action(sig, dr):
        La = L1 @ cay(sig)
        ra = r1 + dr
        xi_a = cay_inv(np.swapaxes(L0, 1, 2) @ La)
        xi_b = cay_inv(np.swapaxes(La, 1, 2) @ L2)
        s = 0.0
        for (Ln, rn, xi, r_1) in ((L0, r0, xi_a, ra), (La, ra, xi_b, r2)):
            e, n = model.rod.lagrangian_pieces(h, Ln, rn, xi, r_1)
            s += e.sum() + n.sum()
        return s

    xi01 = cay_inv(np.swapaxes(L0, 1, 2) @ L1)
    xi12 = cay_inv(np.swapaxes(L1, 1, 2) @ L2)
    grad = model.rod.derivative(h, L0, r0, xi01, r1, level=1) + model.rod.derivative(h, L1, r1, xi12, r2, level=0)
    zero = np.zeros((model.N + 1, 3))
    fd = np.zeros_like(grad)
    for j in range(model.N + 1):
        for d in range(6):
            e = 1e-6
            sp, dp = zero.copy(), zero.copy()
            (dp if d < 3 else sp)[j, d % 3] = e
            fd[j, d] = (action(sp, dp) - action(-sp, -dp)) / (2 * e)
    assert np.allclose(grad, fd, atol=1e-6 * np.abs(fd).max()), np.abs(grad - fd).max()


def test_free_tumbling_rod_conserves_momenta_energy_and_orthogonality():
    """Spin about an oblique axis (h |omega| = 0.5 per step): the rod flexes under centrifugal loads.

    Momenta to round-off, energy bounded, frames orthogonal.  (A free rod with uniform initial
    curvature is not admissible data: its free ends carry an unbalanced moment.)
    """
    model = build_model(tumbling_scene())
    sim = Simulation(model)
    sim.step()
    m1 = sim.monitors()
    P, J, E = m1["linear_momentum"], m1["angular_momentum"], m1["energy"]
    worst = {"P": 0.0, "J": 0.0, "E": 0.0, "orth": 0.0}
    xi_max = 0.0
    for _ in range(400):
        sim.step()
        mo = sim.monitors()
        xi_max = max(xi_max, np.max(np.linalg.norm(sim.state.v[3 * (model.N + 1):].reshape(-1, 3), axis=1)))
        worst["P"] = max(worst["P"], np.max(np.abs(mo["linear_momentum"] - P)) / np.linalg.norm(P))
        worst["J"] = max(worst["J"], np.max(np.abs(mo["angular_momentum"] - J)) / np.linalg.norm(J))
        worst["E"] = max(worst["E"], abs(mo["energy"] - E) / E)
        worst["orth"] = max(worst["orth"], mo["frame_orthogonality"])
    assert xi_max > 0.45  # genuinely large rotations per step
    assert worst["P"] < 1e-12 and worst["J"] < 1e-12, worst
    assert worst["orth"] < 1e-13, worst
    assert worst["E"] < 5e-3, worst  # measured 1.7e-3 (0.1 allowed 0.05)


def test_free_rod_far_from_the_origin_keeps_momenta_at_round_off():
    """A tumbling rod thrown at 374 m/s under gravity ends 1.5 km from the origin after 400 steps.

    Positions relative to the floating origin keep the momentum balance at round-off; with absolute
    coordinates (floating_origin off) the angular momentum error is 500x larger.  The energy monitor
    must not see the origin's moves (gravity is linear in r: its origin part is added exactly).
    """
    g = np.array([0.0, 0.0, -9.81])
    errors = {}
    for floating in (True, False):
        model = build_model(rod_scene(nodes=11, h=1e-2, section=STIFF, gravity=list(g),
                                      initial=dict(SPIN, velocity=[300.0, -200.0, 100.0])))
        sim = Simulation(model)
        sim.stepper.floating_origin = floating
        M = float(np.sum(model.rod.section.rhoA * model.rod.w))
        sim.step()
        m1 = sim.monitors()
        P1, J1, E1 = m1["linear_momentum"], m1["angular_momentum_cm"], m1["energy"]
        worst = {"P": 0.0, "J": 0.0}
        energies = []
        for k in range(2, 402):
            sim.step()
            mo = sim.monitors()
            P_exact = P1 + (k - 1) * sim.h * M * g  # gravity's impulse, exactly m g h per step
            worst["P"] = max(worst["P"], np.max(np.abs(mo["linear_momentum"] - P_exact)) / np.linalg.norm(P1))
            worst["J"] = max(worst["J"], np.max(np.abs(mo["angular_momentum_cm"] - J1)) / np.linalg.norm(J1))
            energies.append(mo["energy"])
        errors[floating] = worst
        if floating:
            assert np.linalg.norm(sim.fields()["rod/r"][0]) > 1400.0
            E_floating = np.array(energies)
        else:
            # the energy monitor reads the same with and without the origin's moves
            assert np.max(np.abs(E_floating - np.array(energies))) < 1e-9 * abs(E1)
    assert errors[True]["P"] < 1e-13 and errors[True]["J"] < 1e-12, errors  # measured 1e-15 / 4e-14 (no gravity)
    assert errors[False]["J"] > 10 * errors[True]["J"], errors


def test_a_step_too_large_for_the_rotation_fails_with_one_line_and_keeps_the_file(tmp_path, capsys):
    """h|omega| = 5 (the rigid rotation alone is 136 degrees per step): Newton may converge, but to
    frames turning by ~170 degrees per step with the energy off by O(1).  The run stops with one line
    naming the step and the node; what was written stays readable.  (Before: a traceback from a
    division by zero where an iterate reached the Cayley chart's singularity, or a wrong result.)"""
    from varint.cli import main
    from varint.run.io import read_run

    example = Path(__file__).resolve().parent.parent / "examples" / "tumbling_rod.toml"
    f = tmp_path / "big_step.toml"
    f.write_text(example.read_text().replace("step = 5.0e-3", "step = 0.1").replace("every = 4", "every = 1"))
    out = tmp_path / "big_step.h5"
    assert main(["run", str(f), "-o", str(out), "-q"]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "turns by" in err[0] and "reduce time.step" in err[0], err
    run = read_run(out)
    assert len(run["time"]) >= 1 and np.all(np.isfinite(run["fields"]["rod/r"]))


def test_static_of_a_free_rod_is_refused_in_one_line(tmp_path, capsys):
    """Free-free and not spinning: no unique static equilibrium (before: a scipy singular-matrix warning
    and, after 256 load steps, a misleading "did not converge")."""
    from varint.cli import main

    d = {"title": "free", "tube": {"length": 1.0, "nodes": 11, "radius": 0.01},
         "rod": dict(SECTION, ends={"s0": "free", "sL": "free"}, load={"force": [0.0, 1.0, 0.0]}),
         "time": {"step": 1e-3, "end": 1.0}}
    f = tmp_path / "free.toml"
    f.write_text(to_toml(d))
    assert main(["static", str(f), "-o", str(tmp_path / "s.h5")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "both rod.ends free" in err[0], err


def test_planar_free_rod_is_free():
    """The planar model masks its out-of-plane directions everywhere, so "free" must come from the ends,
    not the mask: a planar free rod translating gets its modes (it was refused as "supported") and a
    floating origin, like the 3D one."""
    planar = build_model(rod_scene(nodes=11, dimension=2, initial={"velocity": [1.0, 0.5, 0.0]}))
    spatial = build_model(rod_scene(nodes=11, dimension=3, initial={"velocity": [1.0, 0.5, 0.0]}))
    assert planar.rod.free and spatial.rod.free and Simulation(planar).stepper.floating_origin
    f2 = [m["frequency"] for m in rod_modes(planar, count=8)]
    f3 = [m["frequency"] for m in rod_modes(spatial, count=30)]
    elastic = [f for f in f2 if f > 1.0]
    assert elastic and all(min(abs(np.array(f3) / f - 1)) < 1e-9 for f in elastic)
    assert not build_model(rod_scene(nodes=11, dimension=2, ends=("pinned", "free"))).rod.free


# -- the benchmark cantilever of scripts/bench_pyelastica.py and docs/performance.md (PyElastica's section form,
#    varint.scene.standard.solid_section): L = 1 m, solid radius 1 cm, rho = 1000, G = E/1.5

def _bending(freqs, targets):
    freqs = np.asarray(freqs)
    return np.array([freqs[np.argmin(np.abs(freqs - w))] for w in targets])


@pytest.mark.validation
@pytest.mark.slow  # 0.4-0.8 min: the slow tier (tests/conftest.py; CI runs it)
def test_cantilever_frequencies_against_timoshenko_and_euler_bernoulli_order_two():
    from varint.exact.beams import euler_bernoulli_cantilever, timoshenko_cantilever

    sec = solid_section()
    tim = timoshenko_cantilever(sec["bending_stiffness"], sec["shear_stiffness"], sec["mass_per_length"], sec["rotary_inertia"], 1.0)
    eb = euler_bernoulli_cantilever(sec["bending_stiffness"], sec["mass_per_length"], 1.0)
    errs = []
    for N in (25, 50, 100):
        model = build_model(rod_scene(nodes=N + 1, dimension=2, section=sec, ends=("clamped", "free"), measure="reference"))
        f = _bending([m["frequency"] for m in rod_modes(model, count=12)], tim)
        errs.append(np.abs(f / tim - 1))
    errs = np.array(errs)
    orders = np.log2(errs[:-1] / errs[1:])
    assert np.all(np.abs(orders - 2) < 0.2), orders
    assert np.all(errs[-1] < 1e-4)  # 100 elements: 2.6e-5, 2.4e-5, 5.9e-5
    # Euler-Bernoulli differs from Timoshenko by shear and rotary inertia: (r/L)^2-small for this rod
    assert np.all(np.abs(f / eb - 1) < 3e-3)


@pytest.mark.validation
def test_3d_modes_equal_planar_modes_in_plane():
    sec = solid_section()
    f2 = [m["frequency"] for m in rod_modes(build_model(rod_scene(nodes=21, dimension=2, section=sec, ends=("clamped", "free"))), count=4)]
    f3 = [m["frequency"] for m in rod_modes(build_model(rod_scene(nodes=21, dimension=3, section=sec, ends=("clamped", "free"))), count=8)]
    # every planar bending frequency appears twice in 3D (two bending planes)
    for w in f2[:3]:
        assert np.sum(np.isclose(f3, w, rtol=1e-6)) == 2


@pytest.mark.validation
def test_axial_and_torsional_wave_speeds():
    """Clamped-free axial and torsional modes: omega_n = (2n-1) pi c / (2L), c = sqrt(E/rho), sqrt(G/rho)."""
    sec = solid_section(E=1e6)
    model = build_model(rod_scene(nodes=101, dimension=3, section=sec, ends=("clamped", "free"), measure="reference"))
    f = np.array([m["frequency"] for m in rod_modes(model, count=60)])
    c_ax, c_tor = math.sqrt(1e6 / 1000.0), math.sqrt(1e6 / 1.5 / 1000.0)
    for c in (c_ax, c_tor):
        for n in (1, 2):
            w = (2 * n - 1) * math.pi * c / 2.0
            assert np.min(np.abs(f / w - 1)) < 2e-4


def test_static_cantilever_against_the_elastica():
    """Dead tip load P L^2 / EI = 4: tip rotation 64 degrees; stiff stretch/shear to compare with the inextensible elastica."""
    from varint.exact.beams import elastica_cantilever_tip

    sec = solid_section(stretch_factor=1e6)
    EI = sec["bending_stiffness"]
    xe, ye, the = elastica_cantilever_tip(4 * EI, EI, 1.0)
    assert abs(math.degrees(the)) > 60
    model = build_model(rod_scene(nodes=51, dimension=2, section=sec, ends=("clamped", "free"), measure="reference",
                                  load={"force": [0.0, -4 * EI, 0.0]}))
    Lam, r, info = static_equilibrium(model)
    assert abs(r[-1, 0] - xe) < 3e-4 and abs(r[-1, 1] - ye) < 3e-4, (r[-1], xe, ye)
    tip_angle = math.atan2(Lam[-1][1, 0], Lam[-1][0, 0])
    assert abs(tip_angle - the) < 1e-3


def test_gravity_changes_momentum_by_exactly_m_g_h():
    g = np.array([0.0, -9.81, 0.0])
    model = build_model(rod_scene(nodes=11, h=1e-3, section=STIFF, measure="reference", gravity=list(g),
                                  initial={"angular_velocity": [3.0, 5.0, -2.0]}))
    sim = Simulation(model)
    mass = sim.monitors()["mass"]
    P_prev, J_prev = sim.monitors()["linear_momentum"], sim.monitors()["angular_momentum"]
    for _ in range(50):
        sim.step()
        mo = sim.monitors()
        assert np.allclose(mo["linear_momentum"] - P_prev, mass * g * sim.h, rtol=0, atol=1e-13)
        # gravity exerts no torque about its own axis
        assert abs(mo["angular_momentum"][1] - J_prev[1]) < 1e-13
        P_prev, J_prev = mo["linear_momentum"], mo["angular_momentum"]


def test_rod_run_file_has_rod_fields_and_monitors(tmp_path):
    from varint import run_scene
    from varint.run.io import read_run

    scene = rod_scene(nodes=11, h=1e-3, end=2e-2, section=STIFF, initial={"angular_velocity": [0.0, 0.0, 5.0]})
    run_scene(scene, str(tmp_path / "rod.h5"), progress=False)
    run = read_run(tmp_path / "rod.h5")
    assert run["fields"]["rod/r"].shape == (21, 11, 3)
    assert run["fields"]["rod/Lambda"].shape == (21, 11, 3, 3)
    for k in ("energy", "kinetic_energy", "linear_momentum", "angular_momentum", "angular_momentum_cm", "frame_orthogonality"):
        assert k in run["monitors"]
    assert np.max(run["monitors"]["frame_orthogonality"]) < 1e-14
    # the plot shows the rod's invariants, not the tube's "fluid momentum"
    from varint.plotting import monitor_panels, plot_run

    labels = [label for label, _ in monitor_panels(run["monitors"])]
    assert any("angular momentum" in x for x in labels) and any("orthogonality" in x for x in labels)
    assert not any("fluid" in x for x in labels)
    J = dict(monitor_panels(run["monitors"]))["change of angular momentum [kg m2/s]"][0][1]
    assert J[0] == 0.0 and np.max(J) < 1e-12  # a free spinning rod: |J_cm - J_cm0| at round-off
    assert len(plot_run(tmp_path / "rod.h5", tmp_path / "png")) == 2
    from varint.run.io import summary

    d = summary(tmp_path / "rod.h5")  # what `varint info` prints
    assert d["angular_momentum_cm_deviation"] < 1e-12 and d["linear_momentum_deviation"] < 1e-12
    assert d["frame_orthogonality_max"] < 1e-14


@pytest.mark.validation
def test_hard_stiff_shear_and_stretch_at_100x_the_explicit_limit():
    """Stretch and shear stiffness 1e4 EI/L^2; h = 100 x (2 / omega_max): stable, energy kept, bending accurate."""
    from varint.analysis.signals import zero_crossing_frequency

    sec = solid_section(stretch_factor=1e4)
    EI = sec["bending_stiffness"]
    loaded = build_model(rod_scene(nodes=21, dimension=2, section=sec, ends=("clamped", "free"), measure="reference",
                                   load={"force": [0.0, -0.5 * EI, 0.0]}))
    f = np.array([m["frequency"] for m in rod_modes(loaded, count=1000)])
    w1, w_max = f[0], f[-1]
    Lam, r, _ = static_equilibrium(loaded)  # released from its static deflection: ~10 degrees at the tip
    h = 100 * 2.0 / w_max
    model = build_model(rod_scene(nodes=21, dimension=2, section=sec, ends=("clamped", "free"), measure="reference", h=h))
    model.rod.Lam0, model.rod.r0 = Lam, r
    sim = Simulation(model)
    t, y, E = [], [], []
    for _ in range(int(2 * 2 * math.pi / w1 / h)):
        sim.step()
        t.append(sim.state.t)
        y.append(sim.state.q[3 * model.N + 1])
        E.append(sim.monitors()["energy"])
    E = np.array(E)
    assert len(f) == loaded.nz  # the whole spectrum, so w_max is the highest frequency and h is 100x the limit
    assert (E.max() - E.min()) / E[0] < 1e-4  # measured 1.1e-5
    assert np.max(np.abs(y)) < 0.17  # bounded: the tip swings between its +-0.161 m extremes
    omega = zero_crossing_frequency(np.array(t), np.array(y))
    assert omega == pytest.approx(w1, rel=2e-3)  # measured 5.6e-4


@pytest.mark.convergence
@pytest.mark.parametrize("wave", ["axial", "torsional"])
def test_wave_order_two_in_h(wave):
    """Released from the first axial (torsional) mode shape: the tip response converges at order 2 in h."""
    sec = solid_section(E=1e6)
    c = math.sqrt(1e6 / 1000.0) if wave == "axial" else math.sqrt(1e6 / 1.5 / 1000.0)
    T = 0.6 * 4.0 / c  # 0.6 of the first period 4L/c

    def tip(h):
        model = build_model(rod_scene(nodes=21, dimension=3, section=sec, ends=("clamped", "free"), measure="reference", h=h))
        s = np.linspace(0.0, 1.0, 21)
        amp = 1e-3 * np.sin(0.5 * math.pi * s)
        if wave == "axial":
            model.rod.r0 = model.rod.r0 + np.outer(amp, [1.0, 0.0, 0.0])
        else:
            model.rod.Lam0 = cay(np.outer(amp, [1.0, 0.0, 0.0]) * 2.0)  # twist angle ~ 1e-3 sin(pi s / 2)
        sim = Simulation(model)
        for _ in range(int(round(T / h))):
            sim.step()
        f = sim.fields()
        Lam, r = f["rod/Lambda"], f["rod/r"]
        return r[-1, 0] if wave == "axial" else cay_inv(Lam[-1])[0]

    h0 = T / 20
    ref = tip(h0 / 32)
    errs = [abs(tip(h0 / k) - ref) for k in (1, 2, 4)]
    orders = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    assert np.all(np.abs(orders - 2) < 0.2), (errs, orders)


def test_planar_rod_is_a_reduced_model():
    m2 = build_model(rod_scene(nodes=11, dimension=2, ends=("clamped", "free")))
    m3 = build_model(rod_scene(nodes=11, dimension=3, ends=("clamped", "free")))
    assert m2.nz == 3 * 10 and m3.nz == 6 * 10  # (x, y, theta) against (r, Lambda) per free node
    assert m2.rod.layout == {"r": 20, "Lambda": 10}
    pinned = build_model(rod_scene(nodes=11, dimension=3, ends=("pinned", "free")))
    assert pinned.nz == 6 * 10 + 3  # a pinned end keeps its rotation


def test_cli_static_and_modes(tmp_path, capsys):
    import json

    from varint.cli import main
    from varint.run.io import read_run

    example = Path(__file__).resolve().parent.parent / "examples" / "cantilever_rod.toml"
    out = tmp_path / "static.h5"
    assert main(["static", str(example), "-o", str(out)]) == 0
    run = read_run(out)
    tip = run["fields"]["rod/r"][0, -1]
    from varint.exact.beams import elastica_cantilever_tip

    xe, ye, _ = elastica_cantilever_tip(4.0, 1.0, 1.0)  # the example's load is P L^2 / EI = 4
    # the real section stretches and shears: measured 1.6e-4 and -7.6e-5 from the inextensible elastica
    assert abs(tip[0] - xe) < 4e-4 and abs(tip[1] - ye) < 4e-4, (tip, xe, ye)
    capsys.readouterr()
    assert main(["modes", str(example), "--json", "-n", "3"]) == 0
    modes = json.loads(capsys.readouterr().out)["modes"]
    assert len(modes) == 3 and modes[0]["frequency"] == pytest.approx(0.5558, rel=2e-3)
    assert all(m["growth_rate"] == 0.0 for m in modes)


@pytest.mark.parametrize("level", [0, 1])
@pytest.mark.parametrize("measure", ["paper", "reference"])
def test_pieces_kernel_equals_numpy_reference(level, measure):
    model = build_model(rod_scene(measure=measure, gravity=[0.3, -9.81, 0.5], load={"force": [1.0, -2.0, 0.5]}))
    rng = np.random.default_rng(9)
    (L0, r0), (L1, r1), _ = _random_levels(model, rng, amp=0.3)
    xi = cay_inv(np.swapaxes(L0, 1, 2) @ L1)
    sig = (rng.standard_normal((4, model.N + 1, 3)) + 1j * rng.standard_normal((4, model.N + 1, 3))) * 1e-2
    dr = (rng.standard_normal((4, model.N + 1, 3)) + 1j * rng.standard_normal((4, model.N + 1, 3))) * 1e-3
    ref = model.rod.lagrangian_pieces(1e-3, L0, r0, xi, r1, sig, dr, level)
    fast = model.rod.pieces_fast(1e-3, L0, r0, xi, r1, sig, dr, level)
    for a, b in zip(ref, fast):
        assert np.allclose(a, b, rtol=1e-12, atol=1e-14 * np.abs(a).max())


@pytest.mark.parametrize("dimension", [2, 3])
def test_accumulate_kernel_equals_numpy_reference(dimension):
    """The numba accumulation of complex-step pieces into nodal derivatives equals its NumPy twin."""
    from varint.terms.rod import _k_accumulate

    model = build_model(rod_scene(nodes=8, dimension=dimension))
    _, _, colour, direction = model.rod._cs_plan()
    B = len(colour)
    rng = np.random.default_rng(5)
    elem = rng.standard_normal((B, model.N)) + 1j * rng.standard_normal((B, model.N))
    node = rng.standard_normal((B, model.N + 1)) + 1j * rng.standard_normal((B, model.N + 1))
    out = np.zeros((model.N + 1, 6))
    _k_accumulate(elem, node, colour, direction, 1e30, out)
    assert np.allclose(out, model.rod.accumulate_reference(elem, node), rtol=1e-14, atol=0)


@pytest.mark.validation
@pytest.mark.parametrize("scheme", ["midpoint", "energy-momentum"])
@pytest.mark.slow  # 0.5-1.7 min: the slow tier (tests/conftest.py; CI runs it)
def test_cantilever_frequencies_from_a_time_domain_run(scheme):
    """Released from a mix of the first three modes: each modal coordinate oscillates at its Timoshenko frequency
    (outside truth for both time schemes: the midpoint and the energy-momentum step of docs/theory.md §12a)."""
    from varint.analysis.signals import zero_crossing_frequency
    from varint.exact.beams import timoshenko_cantilever
    from varint.model.statics import retract

    sec = solid_section()
    tim = timoshenko_cantilever(sec["bending_stiffness"], sec["shear_stiffness"], sec["mass_per_length"], sec["rotary_inertia"], 1.0)
    h = 2 * math.pi / tim[2] / 40
    model = build_model(rod_scene(nodes=41, dimension=2, section=sec, ends=("clamped", "free"), measure="reference", h=h))
    res, X = rod_modes(model, count=3, vectors=True)
    Mv = lumped_mass(model)[model.rod.mask]
    # 1 mm tip amplitude in each mode
    z = sum(X[:, i] * 1e-3 / np.max(np.abs(X[1::3, i])) for i in range(3))  # planar unknowns: (x, y, theta) per node
    Lam0, r0 = model.rod.Lam0.copy(), model.rod.r0.copy()
    model.rod.Lam0, model.rod.r0 = retract(Lam0, r0, z, model.rod.mask)
    sim = Simulation(model, scheme=scheme)
    n = int(1.6 * 2 * math.pi / tim[0] / h)
    t, q = np.empty(n), np.empty((n, 3))
    for k in range(n):
        sim.step()
        f = sim.fields()
        Lam, r = f["rod/Lambda"], f["rod/r"]
        u = np.concatenate([r - r0, cay_inv(np.swapaxes(Lam0, 1, 2) @ Lam)], axis=1)[model.rod.mask]
        t[k], q[k] = sim.state.t, X.T @ (Mv * u)
    for i in range(3):
        w = zero_crossing_frequency(t, q[:, i])
        assert w == pytest.approx(tim[i], rel=3e-3), (i, w, tim[i])


@pytest.mark.validation
@pytest.mark.parametrize("ratio", [0.9, 1.1])
def test_euler_buckling_threshold_from_modes_about_the_loaded_equilibrium(ratio, tmp_path, capsys):
    """Cantilever column under a dead compressive tip load: unstable (growth rate > 0) above P_cr = pi^2 EI / (4 L^2)."""
    import json

    from varint.cli import main

    sec = solid_section(stretch_factor=1e5)
    EI = sec["bending_stiffness"]
    P = ratio * math.pi ** 2 * EI / 4.0
    d = {"title": "column", "tube": {"length": 1.0, "nodes": 41, "radius": 0.01},
         "rod": dict(sec, dimension=2, ends={"s0": "clamped", "sL": "free"}, load={"force": [-P, 0.0, 0.0]}),
         "time": {"step": 1e-3, "end": 1.0}}
    f = tmp_path / "column.toml"
    f.write_text(to_toml(d))
    assert main(["modes", str(f), "--about", "static", "--json", "-n", "2"]) == 0
    lowest = json.loads(capsys.readouterr().out)["modes"][0]
    if ratio < 1:
        assert lowest["growth_rate"] == 0.0 and lowest["frequency"] > 0
    else:
        assert lowest["growth_rate"] > 0 and lowest["frequency"] == 0.0


def test_rod_resume_equals_uninterrupted(tmp_path):
    from varint import run_scene
    from varint.run.io import read_run

    scene = rod_scene(nodes=11, h=1e-2, end=0.4, section=STIFF, initial={"angular_velocity": [13.0, 40.0, -27.0]})
    run_scene(scene, str(tmp_path / "full.h5"), progress=False)
    run_scene(scene, str(tmp_path / "part.h5"), progress=False, max_steps=17)
    run_scene(scene, str(tmp_path / "part.h5"), resume=True, progress=False)
    a, b = read_run(tmp_path / "full.h5"), read_run(tmp_path / "part.h5")
    assert np.array_equal(a["time"], b["time"])
    for k in ("rod/r", "rod/Lambda"):
        assert np.allclose(a["fields"][k], b["fields"][k], rtol=0, atol=1e-12)


def test_rod_perturbation_adds_node_velocities_and_leaves_held_nodes_at_rest():
    """rod.perturbation[]: a velocity profile along the reference arc length in a direction (normalised),
    added to the rigid motion of rod.initial; the clamped node does not move; the run's initial kinetic energy
    is the lumped one of those velocities."""
    pert = [{"field": "velocity", "shape": "cosine", "wavelength": 2.0, "amplitude": 0.02, "direction": [0.0, 2.0, 0.0]}]
    model = build_model(rod_scene(nodes=11, ends=("clamped", "free"), dimension=2, perturbation=pert))
    rod = model.rod
    s = rod.ds * np.arange(rod.N + 1)
    expected = 0.02 * np.cos(2 * np.pi * s / 2.0)
    expected[0] = 0.0
    assert np.allclose(rod.v0[:, 1], expected, rtol=0, atol=1e-15) and not np.any(rod.v0[:, [0, 2]])
    sim = Simulation(model)
    kinetic = 0.5 * np.sum(rod.node_mass * expected ** 2)
    assert sim.monitors()["energy"] == pytest.approx(kinetic, rel=1e-6)
