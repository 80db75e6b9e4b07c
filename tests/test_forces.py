"""Non-conservative forces by discrete Lagrange–d'Alembert, and invariants derived from declarations.

Outside truths: a dead torque T changes the angular momentum by exactly h T per step and the linear
momentum not at all (the discrete Noether theorem with forces, Marsden & West 2001 §3.2); a shaft on
two pins keeps its angular momentum about the line through them; the work of a constant torque over a
rotation by theta about a fixed axis is T.a theta.
"""

import math

import numpy as np
import pytest

from varint import build_model, make_simulation
from varint.terms.forces import Declaration, TipTorque, derive_invariants
from varint.lattice.lie import cay

from varint.scene.standard import rod_scene


def test_derive_invariants_combines_declarations():
    grav = Declaration("gravity", {"linear_momentum": "linear_momentum_transverse_to_gravity",
                                   "angular_momentum": "angular_momentum_along_gravity"})
    assert derive_invariants([Declaration("kinetic")]) == ["energy", "linear_momentum", "angular_momentum"]
    assert derive_invariants([grav]) == ["energy", "linear_momentum_transverse_to_gravity", "angular_momentum_along_gravity"]
    ends = Declaration("ends", {"linear_momentum": None, "angular_momentum": None})
    assert derive_invariants([grav, ends]) == ["energy"]  # a support removes what gravity left
    torque = TipTorque([0.0, 0.0, 1.0]).declaration
    assert derive_invariants([torque]) == ["linear_momentum"]
    bearing = Declaration("ends", {"linear_momentum": None, "angular_momentum": "angular_momentum_about_the_bearing_axis"})
    assert derive_invariants([bearing, grav]) == ["energy"]  # two different survivors: none is kept


@pytest.mark.parametrize("case, expected", [
    ({}, ["energy", "linear_momentum", "angular_momentum"]),
    ({"gravity": [0.0, -9.81, 0.0]}, ["energy", "linear_momentum_transverse_to_gravity", "angular_momentum_along_gravity"]),
    ({"ends": ("clamped", "free")}, ["energy"]),
    ({"ends": ("pinned", "pinned")}, ["energy", "angular_momentum_about_the_bearing_axis"]),
    ({"load": {"torque": [0.0, 0.0, 0.3]}}, ["linear_momentum"]),
    ({"load": {"force": [0.0, 1.0, 0.0]}}, ["energy"]),
], ids=["free", "gravity", "cantilever", "bearings", "tip-torque", "tip-force"])
def test_rod_invariants_follow_from_the_declarations(case, expected):
    model = build_model(rod_scene(nodes=5, **case))
    assert model.rod.expected_invariants() == expected
    assert model.describe()["invariants"] == expected


def _run(scene, steps):
    sim = make_simulation(build_model(scene))
    mons = [sim.monitors()]
    for _ in range(steps):
        sim.step()
        mons.append(sim.monitors())
    P = np.array([m["linear_momentum"] for m in mons])
    J = np.array([m["angular_momentum"] for m in mons])
    return sim, P, J


def test_a_dead_tip_torque_changes_the_angular_momentum_by_h_T_per_step():
    T = np.array([0.02, -0.05, 0.03])
    h, steps = 2e-3, 200
    scene = rod_scene(nodes=9, h=h, initial={"curvature": [0.4, -0.8, 0.3], "angular_velocity": [0.5, 1.0, -0.7]},
                      load={"torque": list(T)})
    sim, P, J = _run(scene, steps)
    dJ = np.diff(J, axis=0)
    scale = np.max(np.abs(J))
    assert np.max(np.abs(dJ - h * T)) < 1e-12 * scale, np.max(np.abs(dJ - h * T))
    # the rod spins about its centre of mass (P = 0): measure P against the momentum its nodes carry
    p_nodes = sim.state.p[: 3 * (sim.model.N + 1)].reshape(-1, 3)
    assert np.max(np.abs(P - P[0])) < 1e-12 * np.sum(np.linalg.norm(p_nodes, axis=1))
    assert np.max(np.abs(J[-1] - J[0])) > 1e3 * 1e-12 * scale  # the torque did change it


def test_a_shaft_on_two_pins_keeps_its_angular_momentum_about_the_bearing_axis():
    scene = rod_scene(nodes=11, h=2e-3, ends=("pinned", "pinned"),
                      initial={"curvature": [0.0, 0.3, 0.2], "angular_velocity": [8.0, 0.0, 0.0]})
    sim, P, J = _run(scene, 300)
    m = sim.model
    p0, p1 = m.rod.r0[0], m.rod.r0[-1]
    axis = (p1 - p0) / np.linalg.norm(p1 - p0)
    Jp = J - np.cross(p0, P)
    about = (Jp - Jp[0]) @ axis
    across = np.linalg.norm((Jp - Jp[0]) - np.outer(about, axis), axis=1)
    scale = np.max(np.abs(J))
    assert np.max(np.abs(about)) < 1e-12 * scale
    assert np.max(across) > 1e-4 * scale  # the reactions of the pins do change the other components


def test_tip_torque_work_is_second_order_in_the_rotation():
    T = np.array([0.0, 0.0, 2.0])
    Lam = np.tile(np.eye(3), (3, 1, 1))
    f = TipTorque(T)
    for theta in (0.2, 0.1, 0.05):
        xi = np.zeros((3, 3))
        xi[-1] = [0.0, 0.0, 2 * math.tan(theta / 2)]  # a rotation by theta about e3
        Lam1 = Lam.copy()
        Lam1[-1] = Lam[-1] @ cay(xi[-1])
        work = f.work(1e-3, Lam, Lam1, xi)
        exact = 2.0 * theta
        assert abs(work / exact - 1 - theta ** 2 / 12) < theta ** 4 / 20


def test_check_lists_the_forces_and_the_derived_invariants(tmp_path, capsys):
    from varint.cli import main

    from varint.scene.text import to_toml

    scene = {"title": "torqued free rod", "tube": {"length": 1.0, "nodes": 5, "radius": 0.01},
             "rod": {"mass_per_length": 0.3, "rotary_inertia": 1e-3, "bending_stiffness": 2.0, "torsional_stiffness": 15.0,
                     "axial_stiffness": 1e5, "shear_stiffness": 8e3, "ends": {"s0": "free", "sL": "free"},
                     "load": {"torque": [0.0, 0.0, 0.1]}},
             "time": {"step": 1e-3, "end": 1e-2}}
    f = tmp_path / "torque.toml"
    f.write_text(to_toml(scene))
    assert main(["check", str(f)]) == 0
    out = capsys.readouterr().out
    assert "non-conservative forces (Lagrange-d'Alembert): tip_torque" in out
    assert "expected invariants: linear_momentum" in out
    scene["rod"]["ends"] = {"s0": "clamped", "sL": "free"}
    f.write_text(to_toml(scene))
    assert main(["check", str(f)]) == 0
    assert "expected invariants: none" in capsys.readouterr().out


def test_the_tip_torque_kernel_is_the_body_torque():
    """k_tip_torque (the one formula of the dead tip torque's discrete forces f^-, f^+ = (h/2) Lambda_N^T T: TipTorque and
    the compiled rod step add it with this kernel) against Lambda_N^T T in NumPy; TipTorque's static force and its
    stiffness block hat(Lambda_N^T T) follow."""
    from varint.lattice.lie import cay, hat
    from varint.terms.forces import TipTorque, k_tip_torque

    rng = np.random.default_rng(6)
    T = rng.normal(size=3)
    Lam = cay(rng.normal(size=(4, 3)))
    f = TipTorque(T)
    out = np.ones(3)
    k_tip_torque(0.25, Lam[-1], T, out)
    assert np.abs(out - 1.0 - 0.25 * Lam[-1].T @ T).max() < 1e-15
    assert np.abs(f.discrete(0.5, Lam)[-1, 3:] - 0.25 * Lam[-1].T @ T).max() < 1e-15
    assert not f.discrete(0.5, Lam)[:-1].any() and not f.discrete(0.5, Lam)[-1, :3].any()
    assert np.abs(f.generalised(Lam)[-1, 3:] - Lam[-1].T @ T).max() < 1e-15
    assert np.abs(f.stiffness_block(Lam) - hat(Lam[-1].T @ T)).max() < 1e-15
