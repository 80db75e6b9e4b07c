"""Step control (docs/theory.md §4b): a step that fails at h is taken as two steps of h/2 (halved again down to
h/8), the run returns to h, the monitors count the halved steps; ``time.adaptive = false`` forbids it."""

import numpy as np
import pytest

from varint import Simulation, build_model, parse_scene
from varint.errors import SolverError
from varint.scene.standard import gas_scene, scene_of, tumbling_scene
from varint.scene.text import to_toml


def _fail_at(stepper, steps, sizes):
    """Make ``stepper`` (and the half steppers it builds) fail its step at h for the levels in ``steps`` when the
    stepper's h is in ``sizes``: as a Newton failure would."""
    real = type(stepper)._step_at_h

    def failing(self):
        if self.h in sizes and self._state.t / self.h + 1 - 1e-9 > 0 and round(self._state.t / sizes[0]) in steps:
            raise SolverError(f"induced failure at h = {self.h:g}")
        return real(self)

    type(stepper)._step_at_h = failing
    return real


@pytest.fixture
def restore_step():
    from varint.schemes.variational import VariationalStepper

    real = VariationalStepper._step_at_h
    yield
    VariationalStepper._step_at_h = real


def test_a_failed_step_is_taken_as_two_half_steps_then_the_run_returns_to_h(restore_step):
    """The tumbling rod at 10 ms: the step from level 3 fails at h (induced); it is taken as two steps of h/2, which
    land where a run at h/2 from the same level lands (to Newton's tolerance), the momenta are kept to round-off
    across it (each half step is a variational step), and the steps after it are at h again."""
    h = 1e-2
    sim = Simulation(build_model(tumbling_scene(h=h)))
    m0 = sim.monitors()
    for _ in range(3):
        sim.step()
    start = sim.state.copy()
    _fail_at(sim.stepper, {3}, [h])
    sim.step()
    assert sim.stats.halved_steps == 1 and sim.monitors()["halved_steps"] == 1
    assert sim.state.n == 4 and abs(sim.state.t - 4 * h) < 1e-15
    ref = Simulation(build_model(tumbling_scene(h=h)), h=h / 2)
    ref.state = start.copy()
    ref.state.n = 6
    ref.step()
    ref.step()
    assert np.abs(sim.state.q - ref.state.q).max() < 1e-9
    for _ in range(3):  # back at h: no more halving
        sim.step()
    assert sim.stats.halved_steps == 1 and sim.state.n == 7
    mo = sim.monitors()
    J0 = np.linalg.norm(m0["angular_momentum"])
    assert np.abs(mo["angular_momentum"] - m0["angular_momentum"]).max() < 1e-12 * J0
    assert np.abs(mo["linear_momentum"] - m0["linear_momentum"]).max() < 1e-12 * J0


def test_halving_goes_down_to_an_eighth_then_the_failure_stops_the_run_at_its_level(restore_step):
    h = 1e-2
    sim = Simulation(build_model(tumbling_scene(h=h)))
    sim.step()
    level = sim.state.copy()
    _fail_at(sim.stepper, {1, 2}, [h, h / 2, h / 4, h / 8])
    with pytest.raises(SolverError, match="induced failure at h = 0.01; time.scheme = 'energy-momentum' may run it"):
        sim.step()
    assert sim.state.n == 1 and np.array_equal(sim.state.q, level.q) and np.array_equal(sim.state.p, level.p)


def test_time_adaptive_false_stops_at_the_first_failure(restore_step):
    d = gas_scene(nodes=9, parcels=8, h=1e-5)
    d["time"]["adaptive"] = False
    sim = Simulation(build_model(scene_of(d)))
    _fail_at(sim.stepper, {0}, [1e-5])
    with pytest.raises(SolverError, match="induced failure"):
        sim.step()
    assert sim.stats.halved_steps == 0


def test_the_scene_key_is_a_boolean():
    d = gas_scene(nodes=9, parcels=8)
    d["time"]["adaptive"] = "yes"
    with pytest.raises(Exception, match="time.adaptive: must be true or false"):
        parse_scene(to_toml(d))



def test_a_failure_left_after_step_control_names_the_energy_momentum_scheme_only_where_it_covers_the_scene(
        restore_step):
    """docs/validation.md "Long runs": the midpoint loses the water-filled hose where the energy-momentum step runs
    it.  A failure that step control cannot recover (``time.adaptive = false`` here) names that scheme when it
    covers the scene (a closed gas tube in a dynamic wall), and leaves the message as it was when it does not (in a
    quasistatic wall, docs/theory.md §12d)."""
    from varint.schemes import em_rod

    for wall, named in (("dynamic", True), ("quasistatic", False)):
        d = gas_scene(nodes=9, parcels=8, h=1e-5)
        d["time"]["adaptive"] = False
        d["wall"]["model"] = wall
        sim = Simulation(build_model(scene_of(d)))
        assert (em_rod.supports(sim.model) is None) == named
        _fail_at(sim.stepper, {0}, [1e-5])
        with pytest.raises(SolverError) as info:
            sim.step()
        assert str(info.value).startswith("induced failure at h = 1e-05")
        assert ("time.scheme = 'energy-momentum'" in str(info.value)) == named, str(info.value)
    # the straight tube's energy-momentum scheme is this step with its discrete-gradient forces: never told to use itself
    d = gas_scene(nodes=9, parcels=8, h=1e-5, scheme="energy-momentum")
    d["time"]["adaptive"] = False
    sim = Simulation(build_model(scene_of(d)))
    _fail_at(sim.stepper, {0}, [1e-5])
    with pytest.raises(SolverError) as info:
        sim.step()
    assert str(info.value) == "induced failure at h = 1e-05"
