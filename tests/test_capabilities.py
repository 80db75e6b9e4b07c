"""The capability table (docs/capabilities.md): every registered scheme on every kind of scene, generated from the
schemes' ``supports`` (varint/capabilities.py).  The page must be current, and every cell a scheme runs must step
and keep the invariants its model declares (tests/helpers.py, ``invariant_error``)."""

from pathlib import Path

import pytest

from helpers import invariant_error
from varint import capabilities as C
from varint.run.simulation import Simulation
from varint.scene.schema import SCHEMA
from varint.schemes.registry import SCHEMES

DOC = Path(__file__).resolve().parent.parent / "docs" / "capabilities.md"
ROWS = C.cells()
RUNS = [(cell, name) for cell, res in ROWS if "scene" not in res for name, why in res.items() if why is None]
STEPS = 4


def test_the_capability_page_is_current():
    assert DOC.read_text(encoding="utf-8") == C.markdown(ROWS), (
        "docs/capabilities.md is stale: python3 -m varint.capabilities > docs/capabilities.md")


def test_the_schema_s_choices_are_the_registered_schemes():
    key = next(k for k in SCHEMA["time"] if k.name == "scheme")
    assert tuple(key.choices) == tuple(SCHEMES) + ("auto",)


@pytest.mark.parametrize("cell, scheme", RUNS, ids=[f"{c.label}-{s}" for c, s in RUNS])
def test_a_cell_that_runs_steps_and_keeps_its_declared_invariants(cell, scheme):
    model, why = C.model_of(cell, scheme)
    assert why is None, why
    sim = Simulation(model, scheme=scheme)
    mons, fields = [sim.monitors()], [sim.fields()]
    for _ in range(STEPS):
        sim.step()
        mons.append(sim.monitors())
        fields.append(sim.fields())
    declared = model.invariants()
    assert declared, "no invariant declared"
    failures = []
    for name in declared:
        err, tol = invariant_error(name, model, mons, fields)
        if not err <= tol:
            failures.append(f"{name}: {err:.3g} > {tol:g}")
    assert not failures, "; ".join(failures)


def test_auto_is_the_energy_momentum_scheme_where_it_covers_the_scene_and_the_midpoint_elsewhere(tmp_path):
    """``time.scheme = "auto"`` (docs/scenes.md): a closed gas tube in a dynamic wall steps with the energy-momentum
    scheme (its energy to the solver's tolerance), the same tube in a quasistatic wall with the midpoint; the run file
    and the model say which."""
    import h5py
    import numpy as np

    from helpers import energy_error_on_motion
    from varint import build_model
    from varint.run.runner import run_scene
    from varint.scene.standard import gas_scene, scene_of

    pulse = [{"field": "pressure", "shape": "gaussian", "amplitude": 2e4, "center": 0.5, "width": 0.1}]
    for wall, expect in (("dynamic", "energy-momentum"), ("quasistatic", "midpoint")):
        d = gas_scene(nodes=17, parcels=16, h=2e-5, end=2e-4, scheme="auto", perturbation=pulse)
        d["wall"]["model"] = wall
        model = build_model(scene_of(d))
        sim = Simulation(model)
        assert sim.scheme.name == expect and model.describe()["scheme"] == expect
        err, _ = energy_error_on_motion(sim, 10)
        assert (err < 1e-9) == (expect == "energy-momentum"), err
        out = tmp_path / f"{wall}.h5"
        run_scene(scene_of(d), str(out), progress=False)
        with h5py.File(out, "r") as f:
            assert f.attrs["scheme"] == expect and np.isfinite(f["monitors/energy"][-1])
