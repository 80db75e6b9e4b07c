"""Observed orders of accuracy by refinement, asserted against the orders the schemes declare.

Space: the lattice is second order (linear radius interpolant, exact parcel volumes; docs/theory.md §3)."""

import numpy as np
import pytest

from varint import Simulation
from varint.stepper import make_scheme

from helpers import gas_scene, make

pytestmark = pytest.mark.convergence

P0 = 101325.0
PERT = [{"field": "pressure", "shape": "cosine", "amplitude": 0.05 * P0, "wavelength": 2.0},
        # sin(2 pi s): vanishes at the closed ends, so the data are compatible with the walls
        {"field": "velocity", "shape": "cosine", "amplitude": 5.0, "wavelength": 1.0, "phase": -np.pi / 2}]


def _final_state(parcels, h, T, scheme="midpoint", wall=True):
    _, model = make(gas_scene(nodes=parcels + 1, parcels=parcels, h=h, perturbation=PERT, scheme=scheme, wall=wall))
    sim = Simulation(model)
    n = int(round(T / h))
    for _ in range(n):
        sim.step()
    return model, sim


def _observables(model, sim, probes=(0.25, 0.5, 0.75)):
    """Positions of the labels that start at the probe points and radii at those nodes: present on every lattice."""
    cfg = model.tube.config(np.concatenate([sim.state.q, sim.state.lam]))
    M, N = model.tube.M, model.N
    out = [cfg.s[int(round(p * M))] for p in probes]
    if model.tube.has_wall:
        out += [cfg.R[int(round(p * N))] for p in probes]
    return np.array(out)


def _orders(errors):
    e = np.asarray(errors)
    return np.log2(e[:-1] / e[1:])


@pytest.mark.parametrize("scheme", ["midpoint", "trapezoidal"])
def test_order_two_in_time(scheme):
    T = 2e-3
    hs = [T / 40, T / 80, T / 160]
    ref_model, ref = _final_state(16, T / 1280, T, scheme)
    ref_obs = _observables(ref_model, ref)
    errs = []
    for h in hs:
        m, s = _final_state(16, h, T, scheme)
        errs.append(np.max(np.abs(_observables(m, s) - ref_obs)))
    orders = _orders(errs)
    declared = make_scheme(ref_model, hs[0], scheme).order
    assert declared == 2
    assert np.all(np.abs(orders - declared) < 0.2), (errs, orders)


@pytest.mark.parametrize("wall", [True, False], ids=["dynamic-wall", "rigid"])
def test_order_two_in_space(wall):
    T, h = 1.5e-3, 2.5e-6
    ref_model, ref = _final_state(256, h, T, wall=wall)
    ref_obs = _observables(ref_model, ref)
    errs = []
    for M in (16, 32, 64):
        m, s = _final_state(M, h, T, wall=wall)
        errs.append(np.max(np.abs(_observables(m, s) - ref_obs)))
    orders = _orders(errs)
    assert np.all(np.abs(orders - 2.0) < 0.2), (errs, orders)
