"""Data that forces change as the run goes (State.data, e.g. the entropy a viscosity raises) is part of the
restart state: written into the checkpoint slot, read back, restored into the model on resume."""

import numpy as np

from varint import Simulation
from varint.run.io import RunWriter, read_checkpoint

from varint.scene.standard import gas_scene
from helpers import make


def test_state_data_goes_through_the_checkpoint_and_back_into_the_model(tmp_path, monkeypatch):
    scene, model = make(gas_scene(nodes=9, parcels=8))
    t = model.tube
    # a part whose parcel entropies evolve (as under a heating viscosity): it reports them and takes them back
    monkeypatch.setattr(t, "evolving_data", lambda: {"S": t.S.copy()}, raising=False)
    monkeypatch.setattr(t, "set_evolving_data", lambda d: t.S.__setitem__(slice(None), d["S"]), raising=False)
    sim = Simulation(model)
    assert set(sim.state.data) == {"S"}
    sim.step()
    heated = t.S + np.linspace(1.0, 2.0, t.M)
    sim.state.data = {"S": heated}
    path = tmp_path / "run.h5"
    w = RunWriter(str(path), scene, sim.h, sim.monitors(), sim.fields())
    try:
        w.append(sim.state.t, sim.monitors(), sim.fields(), sim.state)
        back = read_checkpoint(w.f)
    finally:
        w.close()
    assert np.array_equal(back.data["S"], heated)
    t.S[:] = 0.0
    other = Simulation(model)
    other.state = back  # a resume restores the data into the model
    assert np.array_equal(t.S, heated)
    # a state without data leaves no stale data in the next checkpoint slot
    w = RunWriter(str(path), scene, sim.h, sim.monitors(), sim.fields(), resume=True)
    try:
        st = sim.state.copy()
        st.data = None
        w.append(st.t, sim.monitors(), sim.fields(), st)
        w.append(st.t, sim.monitors(), sim.fields(), st)
        assert read_checkpoint(w.f).data is None
    finally:
        w.close()


def test_a_new_simulation_of_a_model_starts_from_the_initial_data_not_a_heated_run():
    """Shock capturing heats the parcels' entropies in place; a second Simulation of the same model (e.g. to
    halve the step) must start from t = 0's entropies (it started 1e-3 of E too hot)."""
    from pathlib import Path

    from varint import build_model, load_scene

    model = build_model(load_scene(Path(__file__).resolve().parent.parent / "examples" / "sod_shock_tube.toml"))
    first = Simulation(model)
    E0, S0 = first.monitors()["energy"], model.tube.S.copy()
    for _ in range(50):
        first.step()
    assert np.max(model.tube.S - S0) > 1.0  # heated
    second = Simulation(model)
    assert np.array_equal(model.tube.S, S0) and np.array_equal(second.state.data["S"], S0)
    assert second.monitors()["energy"] == E0
