"""Observed orders of accuracy by refinement, asserted against the orders the schemes declare.

Space: the lattice is second order (linear radius interpolant, exact parcel volumes; docs/theory.md §3)."""

import numpy as np
import pytest

from varint import Simulation, build_model
from varint.analysis.signals import observed_orders
from varint.schemes.midpoint import make_scheme
from varint.scene.standard import GAS, coupled_scene, rod_scene

# the smooth wave of varint.scene.standard.smooth_wave_scene run to T, and its labels' positions and radii at three
# probes (present on every lattice): scripts/_runs.py, shared with scripts/validation_report.py
from _runs import gas_final_state, gas_observables

pytestmark = pytest.mark.convergence


@pytest.mark.parametrize("scheme", ["midpoint", "trapezoidal"])
def test_order_two_in_time(scheme):
    T = 2e-3
    hs = [T / 40, T / 80, T / 160]
    ref_model, ref = gas_final_state(16, T / 1280, T, scheme)
    ref_obs = gas_observables(ref_model, ref)
    errs = []
    for h in hs:
        m, s = gas_final_state(16, h, T, scheme)
        errs.append(np.max(np.abs(gas_observables(m, s) - ref_obs)))
    orders = observed_orders(errs)
    declared = make_scheme(ref_model, hs[0], scheme).order
    assert declared == 2
    assert np.all(np.abs(orders - declared) < 0.2), (errs, orders)


@pytest.mark.parametrize("wall", [True, False], ids=["dynamic-wall", "rigid"])
def test_order_two_in_space(wall):
    T, h = 1.5e-3, 2.5e-6
    ref_model, ref = gas_final_state(256, h, T, wall=wall)
    ref_obs = gas_observables(ref_model, ref)
    errs = []
    for M in (16, 32, 64):
        m, s = gas_final_state(M, h, T, wall=wall)
        errs.append(np.max(np.abs(gas_observables(m, s) - ref_obs)))
    orders = observed_orders(errs)
    assert np.all(np.abs(orders - 2.0) < 0.2), (errs, orders)


def _coupled_and_constrained_final(kind, h, T):
    """Final rod positions and label positions (coupled) after T, for the time-order tests."""
    # a soft section with heavy frames, so that every mode of the lattice is resolved at the coarsest step
    # (h omega_max ~ 1): an order is only seen where the motion is resolved
    soft = {"mass_per_length": 0.5, "rotary_inertia": 1e-2, "bending_stiffness": 5.0, "torsional_stiffness": 4.0,
            "axial_stiffness": 200.0, "shear_stiffness": 200.0}
    if kind == "coupled":
        model = build_model(coupled_scene(nodes=7, parcels=8, fluid=GAS, h=h, section=soft,
                                          initial={"curvature": [0.3, 1.0, 0.5], "angular_velocity": [0.0, 0.0, 3.0]},
                                          velocity=2.0, gravity=[0.0, -9.81, 0.0]))
    else:
        scene = rod_scene(nodes=9, h=h, section=soft, initial={"curvature": [0.0, 1.0, 0.5],
                                                               "angular_velocity": [0.0, 0.0, 3.0]})
        scene.rod["constraint"] = "inextensible_unshearable"
        model = build_model(scene)
    sim = Simulation(model)
    for _ in range(int(round(T / h))):
        sim.step()
    out = [sim.fields()["rod/r"].ravel()]
    if kind == "coupled":
        out.append(sim.fields()["fluid/s"])
    return np.concatenate(out)


@pytest.mark.parametrize("kind", ["coupled", "constrained"])
@pytest.mark.slow  # 0.5-1.7 min: the slow tier (tests/conftest.py; CI runs it)
def test_coupled_tube_and_constrained_rod_are_second_order_in_time(kind):
    """The one stepper's order on the new models (docs/theory.md §9a, §10): the midpoint scheme declares 2."""
    # the gas's acoustic modes (2c/ds ~ 5400 rad/s) set the coupled case's resolved step
    T = 0.002 if kind == "coupled" else 0.02
    ref = _coupled_and_constrained_final(kind, T / 640, T)
    # measured orders: coupled 1.94, 2.00; constrained 2.02, 2.02
    errs = [np.max(np.abs(_coupled_and_constrained_final(kind, T / n, T) - ref)) for n in (20, 40, 80)]
    orders = observed_orders(errs)
    assert np.all(np.abs(orders - 2) < 0.25), (errs, orders)
