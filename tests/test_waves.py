"""Small-amplitude waves against results varint did not produce: sound speed, the expandable-tube
dispersion relation (both branches), the Moens-Korteweg speed, and Webster's horn equation."""

import math

import numpy as np
import pytest

from varint import Simulation
from varint.exact.waves import dispersion_branches, webster_frequencies
from varint.analysis.linear import modes

from varint.scene.standard import AIR, AIR_SOUND_SPEED as C0, gas_scene
from helpers import make
from varint.analysis.signals import dominant_wavenumber_index

# the frequency of a fluid field's projection on cos(k x) over a run: scripts/_runs.py, shared with
# scripts/validation_report.py
from _runs import standing_wave_frequency

pytestmark = pytest.mark.validation

RHO0 = AIR["density"]


@pytest.mark.parametrize("scheme", ["midpoint", "trapezoidal", "energy-momentum"])
def test_rigid_tube_sound_speed(scheme):
    """Periodic rigid tube, 64 parcels per wavelength: standing wave at omega = sqrt(gamma p / rho) k."""
    k = 2 * math.pi
    pert = [{"field": "pressure", "shape": "cosine", "amplitude": 10.0, "wavelength": 1.0}]
    _, model = make(gas_scene(nodes=65, parcels=64, wall=False, ends="periodic", h=2e-6, perturbation=pert, scheme=scheme))
    sim = Simulation(model)
    omega = standing_wave_frequency(model, sim, steps=int(3.2 * 2 * math.pi / (C0 * k) / 2e-6), k=k)
    assert omega / k == pytest.approx(C0, rel=5e-4)


def test_expandable_tube_dispersion_both_branches():
    """Modes of the periodic gas-filled rubber tube against the dispersion relation of docs/theory.md §6."""
    _, m = make(gas_scene(nodes=129, parcels=128, ends="periodic"))
    res, X = modes(m, count=m.tube.nq, vectors=True)
    freq = np.array([r["frequency"] for r in res])
    Rpart = X[m.layout["R"], :]
    idx = np.array([dominant_wavenumber_index(Rpart[:, i]) for i in range(X.shape[1])])
    w = m.tube.wall
    checked = 0
    for j in (1, 2, 3):
        k = 2 * math.pi * j / m.L
        lo, hi = dispersion_branches(k, C0, RHO0, m.tube.R0, w.a, w.beta1, w.beta2)
        f = np.sort(freq[(idx == j) & (freq > 1.0)])  # leave out the rigid translation of the fluid
        # each branch is a degenerate (cos, sin) pair
        assert len(f) >= 4
        assert f[0] == pytest.approx(lo, rel=5e-3) and f[1] == pytest.approx(lo, rel=5e-3)
        assert f[2] == pytest.approx(hi, rel=5e-3) and f[3] == pytest.approx(hi, rel=5e-3)
        checked += 1
    assert checked == 3


def test_dispersion_time_domain_low_branch():
    """A standing wave seeded on the low branch oscillates at its frequency in a midpoint run."""
    j = 2
    k = 2 * math.pi * j
    _, probe = make(gas_scene(nodes=129, parcels=128, ends="periodic"))
    w = probe.tube.wall
    lo, _ = dispersion_branches(k, C0, RHO0, probe.tube.R0, w.a, w.beta1, w.beta2)
    # wall displacement in phase with the pressure for this branch (theory.md §6): r = 2 pi R0 p / D
    D = w.beta2 + w.beta1 * k * k - w.a * lo ** 2
    dp = 20.0
    d = gas_scene(nodes=129, parcels=128, ends="periodic", h=1e-6,
                  perturbation=[{"field": "pressure", "shape": "cosine", "amplitude": dp, "wavelength": 1.0 / j}])
    d["wall"]["perturbation"] = [{"field": "R", "shape": "cosine", "amplitude": 2 * math.pi * probe.tube.R0 * dp / D, "wavelength": 1.0 / j}]
    _, model = make(d)
    sim = Simulation(model)
    steps = int(2.2 * 2 * math.pi / lo / 1e-6)
    omega = standing_wave_frequency(model, sim, steps, k)
    assert omega == pytest.approx(lo, rel=5e-3)


def test_moens_korteweg_speed():
    """Liquid in a tube-law wall with a = 0: waves travel at sqrt(A/rho dp/dA) = sqrt(E h / (2 rho R0 (1 - nu^2)))."""
    E, hw, nu, R0, rho = 4e5, 1e-3, 0.0, 0.01, 1050.0
    c_mk = math.sqrt(E * hw / (2 * rho * R0 * (1 - nu ** 2)))
    k = 2 * math.pi
    d = {"title": "MK", "tube": {"length": 1.0, "nodes": 65, "radius": R0},
         "wall": {"model": "quasistatic", "law": "tube-law", "thickness": hw, "youngs_modulus": E, "poisson_ratio": nu},
         "fluid": {"model": "incompressible", "density": rho, "pressure": 0.0, "parcels": 64, "ends": {"s0": "periodic", "sL": "periodic"},
                   "perturbation": [{"field": "velocity", "shape": "cosine", "amplitude": 1e-3, "wavelength": 1.0}]},
         "environment": {"external_pressure": 0.0},
         "time": {"step": 2e-4, "end": 1.0}}
    _, model = make(d)
    sim = Simulation(model)
    omega = standing_wave_frequency(model, sim, steps=int(2.2 * 2 * math.pi / (c_mk * k) / 2e-4), k=k, field="velocity")
    assert omega / k == pytest.approx(c_mk, rel=5e-3)


def test_webster_horn_modes():
    """Closed rigid horn A(s) = A0 exp(2 s): discrete acoustic modes against Webster's equation solved by shooting."""
    L, A0 = 1.0, 1e-3
    area = lambda s: A0 * math.exp(2.0 * s)  # noqa: E731
    xs = np.linspace(0.0, L, 401)
    d = {"title": "horn", "tube": {"length": L, "nodes": 201, "radius": 0.02,
                                   "area_table": [[float(x), area(x)] for x in xs]},
         "fluid": dict(AIR, parcels=200), "time": {"step": 1e-5, "end": 1e-3}}
    _, model = make(d)
    f_model = np.array([r["frequency"] for r in modes(model, count=5)])
    f_webster = webster_frequencies(area, L, C0, count=4)
    assert np.all(f_model > 0)  # closed duct: no rigid translation, every mode oscillates
    f_model = f_model[:4]
    assert np.allclose(f_model, f_webster, rtol=2e-3), (f_model, f_webster)


def test_sparse_tube_modes_equal_the_dense_ones():
    """modes(method="sparse") (shift-invert Lanczos, used above 3000 inertial unknowns) returns the
    dense solver's lowest modes; a 2000-parcel tube (4000 unknowns) takes it by default."""
    from varint.analysis.linear import DENSE_TUBE_MODES_LIMIT

    _, small = make(gas_scene(nodes=33, parcels=32))
    dense = np.array([m["frequency"] for m in modes(small, count=8, method="dense")])
    sparse = np.array([m["frequency"] for m in modes(small, count=8, method="sparse")])
    assert np.allclose(sparse, dense, rtol=1e-10)
    _, big = make(gas_scene(nodes=2001, parcels=2000))
    assert big.tube.nq > DENSE_TUBE_MODES_LIMIT and big.tube.nlam == 0
    f = np.array([m["frequency"] for m in modes(big, count=4)])
    assert np.all(np.abs(f / dense[:4] - 1) < 5e-3)  # the same lowest branch, on a finer lattice


@pytest.mark.parametrize("scheme", ["midpoint", "energy-momentum"])
def test_rigid_tube_sound_speed_of_a_barotropic_liquid(scheme):
    """Periodic rigid tube of a Tait liquid (B = 22 MPa, rho0 = 1000 kg/m^3), 64 parcels per wavelength: standing wave at
    omega = sqrt(B / rho0) k, the liquid's sound speed at its reference density -- the outside truth for the
    energy-momentum scheme's barotropic pressure (docs/theory.md §12d)."""
    k, B, rho0, h = 2 * math.pi, 2.2e7, 1000.0, 5e-6
    c = math.sqrt(B / rho0)
    d = gas_scene(nodes=65, parcels=64, wall=False, ends="periodic", h=h, scheme=scheme)
    d["fluid"] = {"model": "barotropic", "density": rho0, "pressure": 1e5, "bulk_modulus": B, "gamma": 7.0,
                  "parcels": 64, "ends": {"s0": "periodic", "sL": "periodic"},
                  "perturbation": [{"field": "pressure", "shape": "cosine", "amplitude": 10.0, "wavelength": 1.0}]}
    _, model = make(d)
    sim = Simulation(model)
    omega = standing_wave_frequency(model, sim, steps=int(3.2 * 2 * math.pi / (c * k) / h), k=k)
    assert omega / k == pytest.approx(c, rel=5e-4), omega / k / c - 1
