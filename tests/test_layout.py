"""Effects assemble only their own unknowns and terms (docs/theory.md: each effect adds its own unknowns and terms)."""

import numpy as np
import pytest

from varint.errors import SceneError
from varint.scene.standard import gas_scene
from varint.schemes.midpoint import step_terms
from helpers import make


def test_no_wall_means_no_radius_unknowns():
    _, m = make(gas_scene(wall=False))
    assert "R" not in m.layout
    assert m.nz == m.tube.M - 1  # interior labels only
    assert [t.name for t in m.tube.terms] == ["internal"]
    assert m.tube.nlam == 0


def test_no_fluid_means_no_labels():
    d = gas_scene()
    del d["fluid"]
    d["wall"]["perturbation"] = [{"field": "R", "shape": "cosine", "amplitude": 1e-3, "wavelength": 1.0}]
    _, m = make(d)
    assert "s" not in m.layout and "mu" not in m.layout
    assert m.nz == m.N + 1
    assert all(t.name != "internal" for t in m.tube.terms)


def test_dynamic_wall_and_gas_layout():
    _, m = make(gas_scene(nodes=17, parcels=10))
    assert m.layout == {"s": slice(0, 9), "R": slice(9, 26)}
    assert m.tube.nq == 26 and m.tube.nlam == 0


def test_quasistatic_wall_radii_are_algebraic():
    d = gas_scene(nodes=17, parcels=10)
    d["wall"] = {"model": "quasistatic", "beta1": 10.0, "beta2": 1e5}
    _, m = make(d)
    assert m.tube.nq == 9 and m.tube.nlam == 17
    assert np.all(m.tube.mass > 0)


def test_incompressible_adds_one_multiplier_per_parcel():
    d = gas_scene(nodes=17, parcels=10)
    d["fluid"] = {"model": "incompressible", "density": 1000.0, "parcels": 10}
    _, m = make(d)
    assert m.layout["mu"].stop - m.layout["mu"].start == 10
    assert "internal" not in [t.name for t in m.tube.terms]


def test_periodic_labels_and_nodes():
    _, m = make(gas_scene(nodes=17, parcels=10, ends="periodic"))
    assert m.layout["s"] == slice(0, 10)
    assert m.tube.nR == 16


def test_terms_only_for_effects_present():
    d = gas_scene(wall=False)
    d["environment"] = {"external_pressure": 5e4}
    _, m = make(d)
    # a rigid wall takes no work from p_ext
    assert [t.name for t in m.tube.terms] == ["internal"]
    d["environment"]["gravity"] = [9.81, 0.0, 0.0]
    _, m = make(d)
    assert [t.name for t in m.tube.terms] == ["internal", "gravity"]
    # gravity across the fixed axis would do nothing: refused in one line (0.2 dropped it silently)
    d["environment"]["gravity"] = [0.0, 0.0, -9.81]
    with pytest.raises(SceneError, match="environment.gravity: a straight tube"):
        make(d)


def test_invariants_follow_term_declarations():
    _, m = make(gas_scene(wall=False, ends="periodic"))
    assert "axial_momentum" in m.invariants()
    _, m = make(gas_scene(wall=True, ends="periodic"))
    assert "axial_momentum" not in m.invariants()
    d = gas_scene(wall=False, ends="periodic")
    d["environment"] = {"gravity": [1.0, 0.0, 0.0]}
    _, m = make(d)
    assert "axial_momentum" not in m.invariants()
    _, m = make(gas_scene(wall=False, ends="closed"))
    assert "axial_momentum" not in m.invariants() and "parcel_entropy" in m.invariants()


def _rod_model(**rod):
    from varint.scene.standard import rod_scene
    from varint import build_model

    return build_model(rod_scene(**rod))


def test_one_model_whatever_the_effects():
    """Tube and rod scenes build the same Model class; each has only its own blocks and step terms, and
    the one Simulation steps both (no second code path)."""
    from varint import Model, Simulation

    _, tube = make(gas_scene())
    rod = _rod_model(nodes=6, ends=("clamped", "free"))
    assert type(tube) is Model and type(rod) is Model
    assert tube.rod is None and rod.tube is None
    assert set(tube.layout) == {"s", "R"} and set(rod.layout) == {"r", "Lambda"}
    assert [t.name for t in step_terms(tube)] == ["tube_kinetic", "tube_potential"]
    assert [t.name for t in step_terms(rod)] == ["rod"]
    # the clamped node 0 has no unknowns; every other node has 3 + 3; r and Lambda interleave node by node
    assert len(rod.layout["r"]) == len(rod.layout["Lambda"]) == 3 * 5 and rod.nz == 30
    assert np.array_equal(np.sort(np.concatenate([rod.layout["r"], rod.layout["Lambda"]])), np.arange(30))
    assert np.array_equal(rod.layout["r"][:3], [0, 1, 2]) and np.array_equal(rod.layout["Lambda"][:3], [3, 4, 5])
    for model in (tube, rod):
        sim = Simulation(model)
        sim.step()
        assert sim.state.n == 1 and np.isfinite(sim.monitors()["energy"])


def test_a_rod_checkpoint_without_the_floating_origin_resumes():
    """Rod checkpoints written before the floating origin existed hold q = (r, Lambda): assigning such a
    state appends a zero origin, and the step continues exactly as from the same state with it."""
    from varint import Simulation

    model = _rod_model(nodes=6, ends=("clamped", "free"), initial={"curvature": [0.0, 1.0, 2.0]}, gravity=[0.0, 0.0, -9.81])
    sim = Simulation(model)
    sim.step()
    old = sim.state.copy()
    old.q, old.q_prev = old.q[:-3], None
    assert not sim.stepper.floating_origin and not np.any(sim.state.q[-3:])  # a supported rod's origin stays at 0
    other = Simulation(model)
    other.state = old
    assert other.state.q.shape == sim.state.q.shape
    sim.invalidate_jacobian()  # as at a checkpoint: both start from a fresh Jacobian
    sim.step()
    other.step()
    assert np.array_equal(sim.state.q, other.state.q) and np.array_equal(sim.state.p, other.state.p)
