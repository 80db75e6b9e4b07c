"""The periodic rod (rod.ends = periodic; docs/theory.md §9b): node N is node 0's image shifted by the period
L E_1.  Truth: the dispersion relation of the infinite Timoshenko beam and of axial waves at the lattice's
wavenumbers 2 pi n / L; conservation: linear momentum and the angular momentum along the period."""

import math

import numpy as np
import pytest

from varint import Simulation, build_model
from varint.analysis.rod_modes import rod_modes

from varint.scene.standard import ROD_SECTION as SECTION, rod_scene


def timoshenko_wave(k, s=SECTION):
    """Lower (bending) branch of rho A rho I w^4 - (rho A (EI k^2 + kGA) + rho I kGA k^2) w^2 + EI kGA k^4 = 0."""
    EI, kGA, rhoA, rhoI = s["bending_stiffness"], s["shear_stiffness"], s["mass_per_length"], s["rotary_inertia"]
    a, b, c = rhoA * rhoI, -(rhoA * (EI * k * k + kGA) + rhoI * kGA * k * k), EI * kGA * k ** 4
    return math.sqrt((-b - math.sqrt(b * b - 4 * a * c)) / (2 * a))


def test_periodic_rod_modes_are_the_infinite_beam_s_waves_at_second_order():
    errs = []
    for N in (40, 80):
        f = np.array([m["frequency"] for m in rod_modes(build_model(rod_scene(nodes=N + 1, ends=("periodic", "periodic"),
                                                                              dimension=2)), count=8)])
        assert np.all(f[:2] < 1e-3) and f[2] > 10.0  # two translations, and no rotation: it would change the period
        bend = timoshenko_wave(2 * math.pi)
        axial = 2 * math.pi * math.sqrt(SECTION["axial_stiffness"] / SECTION["mass_per_length"])
        assert f[2] == pytest.approx(f[3], rel=1e-9)  # sine and cosine
        errs.append((f[2] / bend - 1, f[6] / axial - 1))
    for i in range(2):
        order = math.log(abs(errs[0][i] / errs[1][i]), 2)
        assert abs(errs[1][i]) < 5e-4 and 1.8 < order < 2.2, (errs, order)


def test_periodic_rod_keeps_its_momenta_and_its_period():
    model = build_model(rod_scene(nodes=21, ends=("periodic", "periodic"), dimension=3,
                                  initial={"velocity": [0.3, 0.2, -0.1], "angular_velocity": [5.0, 0.0, 0.0]}))
    assert model.invariants() == ["energy", "linear_momentum", "angular_momentum_along_the_period"]
    # a periodic wavy shape (bent in y and z, twisted), so that the motion is not rigid
    from varint.lattice.lie import cay

    rod = model.rod
    s_nodes = np.linspace(0.0, 1.0, rod.N + 1)
    wave = np.stack([0.1 * np.sin(2 * np.pi * s_nodes), 0.05 * np.cos(4 * np.pi * s_nodes), 0.08 * np.sin(2 * np.pi * s_nodes)], 1)
    r = rod.r0 + 0.01 * np.stack([0 * s_nodes, np.sin(2 * np.pi * s_nodes), np.cos(2 * np.pi * s_nodes)], 1)
    rod.set_configuration(rod.Lam0 @ cay(wave), r)
    sim = Simulation(model)
    m0 = sim.monitors()
    for _ in range(200):
        sim.step()
        mo = sim.monitors()
        r = sim.fields()["rod/r"]
        Lam = sim.fields()["rod/Lambda"]
        assert np.allclose(r[-1] - r[0], [1.0, 0.0, 0.0], rtol=0, atol=1e-15) and np.array_equal(Lam[-1], Lam[0])
        # round-off of sums of momenta and stiff shear impulses (measured 4.3e-14 over the 200 steps)
        assert np.allclose(mo["linear_momentum"], m0["linear_momentum"], rtol=0, atol=3e-13)
        assert abs(mo["angular_momentum"][0] - m0["angular_momentum"][0]) < 1e-14
        # the wavy start (frames twisted against the centreline) excites the stiff shear modes: the energy error is
        # that of the midpoint rule on them, bounded and falling with h (measured 9.5e-3, 3.8e-3, 1.3e-3 at
        # h = 1, 0.5, 0.25 ms over 0.2 s)
        assert abs(mo["energy"] - m0["energy"]) < 2e-2 * abs(m0["energy"])
