"""The energy-momentum scheme on the straight tube (docs/theory.md §12d): the midpoint step of the labels and radii
with the parcels' pressures and volumes replaced by their discrete gradients (the mean-value pressure of an ideal gas
or a barotropic liquid,
the averaged-vector-field gradient of a swelling parcel's volume).  It keeps the energy to the solver's tolerance
where the midpoint rule keeps it to its O(h^2); its sound speed is tested against sqrt(gamma p / rho) in
tests/test_waves.py."""

from pathlib import Path

import numpy as np
import pytest

from varint import Simulation, build_model, load_scene
from varint.errors import SceneError
from varint.schemes.energy_momentum import straight_tube_stepper
from varint.schemes.variational import VariationalStepper

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


def _energy_error(sim, steps):
    """max |E - E0| over the run, relative to the largest kinetic energy (the energy that moves)."""
    m0 = sim.monitors()
    E, K = [m0["energy"]], [m0["kinetic_energy"]]
    for _ in range(steps):
        sim.step()
        m = sim.monitors()
        E.append(m["energy"])
        K.append(m["kinetic_energy"])
    return float(np.max(np.abs(np.array(E) - E[0])) / max(K))


@pytest.mark.parametrize("example", ["rubber_tube_pulse", "rigid_horn_gas"])
def test_the_energy_is_kept_to_the_solver_tolerance(example):
    """Air in the paper's rubber tube (a swelling wall) and in a rigid horn (a duct of varying area): 150 steps.
    Measured 2.7e-11 and 2.4e-10 of the largest kinetic energy, against the midpoint rule's 2.3e-5 and 1.4e-4 on
    the same steps (the same step without the discrete-gradient force: the check is not vacuous)."""
    scene = load_scene(EXAMPLES / f"{example}.toml")
    em = _energy_error(Simulation(build_model(scene), scheme="energy-momentum"), 150)
    mid = _energy_error(Simulation(build_model(scene), scheme="midpoint"), 150)
    assert em < 1e-9, em
    assert mid > 1e-6, mid


def test_a_scene_s_shock_capturing_is_the_discrete_gradient_force_itself():
    """With [shock_capturing] the model's own force carries the mean-value pressure: no second one is added."""
    model = build_model(load_scene(EXAMPLES / "sod_shock_tube.toml"))
    st = straight_tube_stepper(model, 1e-3)
    assert isinstance(st, VariationalStepper) and st.extra_forces == []
    plain = build_model(load_scene(EXAMPLES / "rubber_tube_pulse.toml"))
    assert len(straight_tube_stepper(plain, 1e-6).extra_forces) == 1


@pytest.mark.parametrize("gamma, wall", [(7.0, True), (1.0, True), (7.0, False), (1.0, False)])
def test_a_barotropic_liquid_keeps_its_energy_to_the_solver_tolerance(gamma, wall):
    """A 3 bar pulse in a Tait liquid (water-like, B = 22 MPa so that the wave crosses parcels in the run), in the
    rubber wall and in a rigid tube, 150 steps: the mean-value pressure of its p = c + K V^-gamma replaces p(Vbar).
    Measured 1.0e-11 to 8.1e-11 of the largest kinetic energy against the midpoint's 1.2e-6 to 8.8e-5."""
    from varint.scene.standard import gas_scene, scene_of

    d = gas_scene(nodes=17, parcels=16, h=2e-5, wall=wall)
    d["fluid"] = {"model": "barotropic", "density": 1000.0, "pressure": 1e5, "bulk_modulus": 2.2e7, "gamma": gamma,
                  "parcels": 16, "initial": [{"from": 0.3, "to": 0.5, "pressure": 3e5}]}
    em = _energy_error(Simulation(build_model(scene_of(d)), scheme="energy-momentum"), 150)
    mid = _energy_error(Simulation(build_model(scene_of(d)), scheme="midpoint"), 150)
    assert em < 1e-9, em
    assert mid > 1e-7, mid


def test_what_it_does_not_cover_is_refused_in_one_line():
    text = (EXAMPLES / "liquid_pulse_tube_law.toml").read_text().replace("[time]\n", '[time]\nscheme = "energy-momentum"\n')
    from varint import parse_scene

    with pytest.raises(SceneError, match=r"^time\.scheme: 'energy-momentum' on the straight tube needs a compressible"):
        Simulation(build_model(parse_scene(text)))


_OPEN_ENDS = {
    "velocity inlet, free jet": 'ends = { s0 = "inflow", sL = "outflow" }',
    "pressure inlet": 'ends = { s0 = "inflow", sL = "outflow", inflow = "pressure", inflow_pressure = 101825.0 }',
    "non-reflecting outlet": 'ends = { s0 = "inflow", sL = "outflow", outflow = "non-reflecting" }',
    "windkessel outlet": ('ends = { s0 = "inflow", sL = "outflow", outflow = "windkessel", windkessel_R1 = 1e5, '
                          'windkessel_C = 1e-9, windkessel_R2 = 1e6 }'),
}


def _open_balance(text, scheme, steps):
    """(largest abs(energy_balance), largest change of it in one step), relative to the energy that moves: the
    largest kinetic energy plus the largest work through the ends (docs/theory.md §13.4)."""
    from varint import parse_scene

    sim = Simulation(build_model(parse_scene(text.replace("[time]\n", f'[time]\nscheme = "{scheme}"\n'))))
    b, K, F = [0.0], 0.0, 0.0
    for _ in range(steps):
        sim.step()
        m = sim.monitors()
        b.append(m["energy_balance"])
        K, F = max(K, m["kinetic_energy"]), max(F, abs(m["energy_flux"]))
    assert m["parcels"] != 200  # parcels entered and left
    b = np.array(b)
    return float(np.max(np.abs(b)) / (K + F)), float(np.max(np.abs(np.diff(b))) / (K + F))


@pytest.mark.parametrize("ends", list(_OPEN_ENDS))
def test_open_ends_energy_balance_closes_every_step_to_the_solver_tolerance(ends):
    """Air through the open rigid pipe of examples/open_pipe_gas.toml (parcels injected and removed, the outlet's
    expansion wave), 300 steps: with the mean-value pressures (terms.open_ends.OpenMeanValuePressure) the energy
    balance -- E now minus E0 minus the work through the ends and what the parcels carried in and out -- closes at
    every step to the solver's tolerance: measured 6e-15 to 1.5e-13 of the energy that moves, against the midpoint's
    1e-8 to 1.2e-7 (its own O(h^2) per step, which the test also sees, so it is not vacuous)."""
    text = (EXAMPLES / "open_pipe_gas.toml").read_text().replace('ends = { s0 = "inflow", sL = "outflow" }',
                                                                  _OPEN_ENDS[ends])
    em, em_step = _open_balance(text, "energy-momentum", 300)
    mid, _ = _open_balance(text, "midpoint", 300)
    assert em < 1e-12 and em_step < 1e-12, (em, em_step)
    assert mid > 1e-9, mid


def test_open_ends_with_a_barotropic_liquid_and_the_refusals():
    """A barotropic liquid through the same pipe closes its balance as the gas does; a [wall] or a duct of varying
    section with open ends is refused in one line naming the key."""
    from varint import parse_scene

    text = (EXAMPLES / "open_pipe_gas.toml").read_text().replace(
        'model = "ideal-gas"\ngamma = 1.4\n', 'model = "barotropic"\nbulk_modulus = 1.0e5\ngamma = 1.4\n')
    em, em_step = _open_balance(text, "energy-momentum", 200)
    assert em < 1e-12 and em_step < 1e-12, (em, em_step)
    horn = (EXAMPLES / "open_pipe_gas.toml").read_text().replace("radius = 0.02\n", "radius = 0.02\narea_table = [[0.0, 1.2e-3], [1.0, 2.0e-3]]\n")
    horn = horn.replace("[time]\n", '[time]\nscheme = "energy-momentum"\n')
    with pytest.raises(SceneError, match=r"^time\.scheme: 'energy-momentum' with open fluid ends .* rigid uniform tube"):
        Simulation(build_model(parse_scene(horn)))


def test_the_open_mean_value_pressure_s_jacobian_is_exact():
    """OpenMeanValuePressure's Newton block against central differences of its force f^- in the new level's labels,
    on the open pipe after 40 steps (parcels entered and left; the piston at its level positions)."""
    from types import SimpleNamespace

    from varint import parse_scene
    from varint.terms.open_ends import OpenMeanValuePressure

    text = (EXAMPLES / "open_pipe_gas.toml").read_text().replace("[time]\n", '[time]\nscheme = "energy-momentum"\n')
    sim = Simulation(build_model(parse_scene(text)))
    for _ in range(40):
        sim.step()
    f = next(x for x in sim.stepper.extra_forces if isinstance(x, OpenMeanValuePressure))
    t = sim.model.tube
    ns = t.layout["s"].stop
    q0 = sim.state.q.copy()
    q1 = q0 + sim.h * sim.state.v * (1.0 + 0.3 * np.sin(np.arange(len(q0))))  # a compressing and expanding guess

    def force(q):
        d = SimpleNamespace(tube_q=np.zeros(ns))
        f.add(SimpleNamespace(q0=q0, q1=q, h=sim.h), d, 0)
        return d.tube_q

    J = f.jacobian(SimpleNamespace(q0=q0, q1=q1, h=sim.h)).toarray()[:ns, :ns]
    e = 1e-7 * t.ell_in
    fd = np.empty_like(J)
    for j in range(ns):
        dq = np.zeros_like(q1)
        dq[j] = e
        fd[:, j] = (force(q1 + dq) - force(q1 - dq)) / (2 * e)
    assert np.max(np.abs(force(q1))) > 0  # the correction is not zero on this step
    assert np.allclose(J, fd, rtol=1e-5, atol=1e-6 * np.max(np.abs(fd)))
