"""A pipe conveying fluid, stepped in time: the coupled tube (docs/theory.md §10) with the liquid flowing.

The periodic pipe (rod and fluid periodic, a stiff quasistatic wall: a rigid closed liquid-filled periodic
tube has an indeterminate pressure, varint/scene/schema.py) carries a plug flow of speed U; a lateral velocity
perturbation cos(k s) starts waves exp(i (k x - omega t)).  Nothing in the discrete Lagrangian names the
Coriolis or the centrifugal force: they come from the fluid labels moving through the Catmull–Rom
centreline.  Truth: the dispersion relation of the flowing Timoshenko pipe
(:func:`varint.exact.beams.flowing_pipe_waves`, Païdoussis vol. 1 §3.2 with shear; docs/theory.md §10.11 shows
that the closed loop's linearisation is that of the open pipe): the Coriolis term splits the two bending
frequencies, the centrifugal one lowers them, and past U_c (where they meet) one wave grows (coupled-mode
flutter; for the Euler–Bernoulli pipe U_c^2 = (m + M) EI k^2 / (m M)).  The frequencies and growth rates
are measured by exponential fits (linear prediction) of the lateral Fourier coefficient.

The perturbation must stay small: lengthening the closed loop by 1/2 int w'^2 squeezes the incompressible
liquid against the stiff wall, and the pressure drop acts as a tension that cancels the excess centrifugal
force at an amplitude of only 5e-4 m at 1.1 U_c (§10.11): at amplitude 1e-3 m/s the "frequencies" of a
two-exponential fit were those of that nonlinear beat.  docs/validation.md ("Flowing pipe, time domain") has
the numbers.
"""

import math

import numpy as np
import pytest

from varint import Simulation, build_model
from varint.analysis.signals import dominant_frequency, two_frequency_fit
from varint.scene.standard import (FLOWING_PIPE_DENSITY as RHO_F, FLOWING_PIPE_K as K, FLOWING_PIPE_RADIUS as RADIUS,
                                   FLOWING_PIPE_STEP as H, FLOWING_PIPE_WALL as WALL, periodic_pipe_critical_speed,
                                   periodic_pipe_scene, periodic_pipe_waves)

# the pipe (varint.scene.standard.periodic_pipe_scene): EI = m = M = 1 (beta = M / (m + M) = 1/2), period L = 1,
# U_c = 8.47 m/s (Timoshenko, 8.89 Euler-Bernoulli); its run, recording the lateral wave, the energy, the momenta and
# the mean pressure: scripts/_runs.py, shared with scripts/flowing_pipe_linear.py
from _runs import periodic_pipe_run

def check_conservation(res):
    """Momenta: the lateral one to round-off, the axial one (which the labels carry) to the Newton tolerance
    (1e-12 on the scaled update; the lateral one measured up to 1.6e-15 of M U L); the energy, relative to the flow's M U^2 L / 2, to the same, bounded."""
    assert res["momentum"] < 1e-14
    assert res["axial_momentum"] < 1e-11
    e = np.abs(res["energy"])
    assert e.max() < 1e-10, e.max()


@pytest.mark.slow  # 0.3-0.4 min: the slow tier (tests/conftest.py; CI runs it)
def test_flowing_pipe_dispersion_relation_and_its_order():
    """U = U_c / 2: the Coriolis-split frequencies converge to the Timoshenko pipe's at second order
    (measured -10.243 / 36.759 at 10 elements and -9.869 / 36.433 at 20 against -9.762 / 36.329; the
    averaged space-discrete linearisation, scripts/flowing_pipe_linear.py, gives -10.243 / 36.756 and
    -9.870 / 36.433: the time step and the label crossings add < 1e-4)."""
    U = 0.5 * periodic_pipe_critical_speed()
    exact = periodic_pipe_waves(U)
    assert exact[0].real < 0.0 < exact[1].real  # one wave runs upstream (against k), one downstream
    split = (exact[0] + exact[1]).real  # the Coriolis split, 2 M U k / (m + M) = U k up to the rotary inertia
    assert split == pytest.approx(U * K, rel=3e-3)
    errs = []
    for nodes in (11, 21):
        res = periodic_pipe_run(U, nodes, 2 * (nodes - 1))
        w = res["omega"] = two_frequency_fit(res["c"], H)
        errs.append([abs(w[i].real / exact[i].real - 1.0) for i in range(2)])
        assert max(abs(x.imag) for x in w) < 5e-4 * abs(exact[1].real)  # neither grows nor decays (< 0.02 /s)
        assert abs((w[0] + w[1]).real / split - 1.0) < 3e-3  # the Coriolis split on every lattice
        check_conservation(res)
    assert max(errs[0]) < 0.06 and max(errs[1]) < 0.015, errs
    for i in range(2):
        order = math.log2(errs[0][i] / errs[1][i])
        assert 1.8 < order < 2.4, (errs, order)


def test_flowing_pipe_is_stable_below_the_critical_speed():
    """0.9 U_c: two real frequencies (measured 12.10 / 35.71 against 12.31 / 35.51), bounded amplitude."""
    U = 0.9 * periodic_pipe_critical_speed()
    exact = periodic_pipe_waves(U)
    assert max(abs(w.imag) for w in exact) == 0.0
    res = periodic_pipe_run(U, 21, 40)
    w = two_frequency_fit(res["c"], H)
    assert max(abs(x.imag) for x in w) < 1e-3 * abs(w[1].real)  # |growth| < 0.04 /s against 12 /s at 1.1 U_c
    for i in range(2):
        assert w[i].real == pytest.approx(exact[i].real, rel=0.03)
    assert res["amplitude"][-300:].max() < 1.5 * res["amplitude"][:300].max()
    check_conservation(res)


@pytest.mark.slow  # 0.3-0.4 min: the slow tier (tests/conftest.py; CI runs it)
def test_flowing_pipe_flutters_above_the_critical_speed():
    """1.1 U_c: one wave grows at the Timoshenko pipe's rate, converging at second order (measured growth
    11.33 / 11.98 1/s at 10 / 20 elements against 12.19; frequency 29.17 / 29.22 against 29.22).  The initial
    velocity 1e-6 m/s keeps the wave linear over the run (amplitude < 5e-5 m)."""
    U = 1.1 * periodic_pipe_critical_speed()
    exact = max(periodic_pipe_waves(U), key=lambda w: w.imag)
    assert exact.imag > 0.0
    errs = []
    for nodes in (11, 21):
        res = periodic_pipe_run(U, nodes, 2 * (nodes - 1), amplitude=1e-6)
        w = dominant_frequency(res["c"][600:], H)  # the decaying wave is down by exp(-2 Im omega t) < 1e-3 there
        errs.append(abs(w.imag / exact.imag - 1.0))
        assert w.real == pytest.approx(exact.real, rel=0.01)
        a = res["amplitude"]
        assert a[-1] > 100.0 * a[:200].max()  # exp(11.3 * 0.5 s) = 290
        assert res["momentum"] < 1e-14 and res["axial_momentum"] < 1e-11
    assert errs[0] < 0.1 and errs[1] < 0.025, errs
    assert 1.7 < math.log2(errs[0] / errs[1]) < 2.5, errs


def test_flowing_pipe_flutter_saturates_by_the_pressure_drop_of_the_lengthened_loop():
    """The nonlinear end of the flutter (docs/theory.md §10.11): the lateral wave lengthens the closed loop by
    1/2 int w'^2, the liquid (fixed volume) squeezes the stiff wall, and the uniform pressure drop dp acts on
    the lateral motion as a tension; the wave stops growing once dp A ~ -M (U^2 - U_c^2), i.e. U_eff = U_c.
    Measured peak drops -15.2 kPa (10 elements) against -15.1 kPa; the dynamic overshoot is allowed 25 %."""
    Uc = periodic_pipe_critical_speed()
    U = 1.1 * Uc
    res = periodic_pipe_run(U, 11, 20, steps=700, amplitude=1e-3)
    area = math.pi * RADIUS ** 2
    M = RHO_F * area
    expected = -M * (U * U - Uc * Uc) / area
    i = int(np.argmin(res["pressure"]))
    assert res["pressure"][i] == pytest.approx(expected, rel=0.25)
    a = res["amplitude"]
    assert a[i] > 5.0 * a[:150].max()  # it grew first ...
    assert a[-1] < 0.9 * a.max()  # ... and then stopped growing
    assert res["momentum"] < 1e-14 and res["axial_momentum"] < 1e-11


@pytest.mark.slow  # 0.3-0.4 min: the slow tier (tests/conftest.py; CI runs it)
def test_liquid_held_at_the_levels_has_no_alternating_mode():
    """The flowing lattice's parasitic mode (docs/theory.md §12, §10.12): in a dynamic wall, 10 elements,
    h = 2.5e-4, 1.1 U_c, the midpoint constraint let the level volumes alternate from step to step and grow
    (3e-12 at 200 steps, 7e-5 at 800, Newton failed at step 1068).  Held at the levels (SHAKE) the run goes on:
    level volumes at the Newton tolerance, energy conserved (measured 3e-12 of the flow's), and the lateral
    wave grows at the flutter rate (measured 11.44 /s against the Timoshenko pipe's 12.19; the 10-element lattice
    gives 11.35, the midpoint runs at h = 5e-4 11.33)."""
    U = 1.1 * periodic_pipe_critical_speed()
    h, steps = 2.5e-4, 1200
    sim = Simulation(build_model(periodic_pipe_scene(U, 11, 20, steps, h, 1e-6, wall=dict(WALL, model="dynamic"))))
    t = sim.model.tube
    m0 = sim.monitors()
    level, energy, c = [], [], []
    for _ in range(steps):
        sim.step()
        cfg, Lam, r, _ = sim.stepper._coupled_levels()
        level.append(np.max(np.abs(sim.stepper._coupled_volumes(cfg, Lam, r) / t.V0 - 1.0)))
        mo = sim.monitors()
        energy.append(abs(mo["energy"] - m0["energy"]) / m0["energy_fluid_kinetic"])
        rr = sim.fields()["rod/r"][:-1]
        c.append(np.mean(rr[:, 1] * np.exp(-1j * K * rr[:, 0])))
        assert mo["constraint_residual"] == level[-1]
    assert max(level) < 1e-12, max(level)
    assert max(energy) < 1e-10, max(energy)
    exact = max(periodic_pipe_waves(U), key=lambda w: w.imag)
    w = dominant_frequency(np.array(c)[600:], h)
    assert w.imag == pytest.approx(exact.imag, rel=0.1)


def test_peak_growth_rate_reads_the_rate_of_a_known_oscillation():
    """varint.analysis.signals.peak_growth_rate (the rate the pipe runs are judged by) on exp(a t) sin(w t), growing and
    decaying, with a transient left out; too few peaks is a ValueError."""
    from varint.analysis.signals import peak_growth_rate

    t = np.linspace(0.0, 10.0, 20001)
    for a in (0.3, -0.45):
        y = np.exp(a * t) * np.sin(5.0 * t + 0.3)
        assert peak_growth_rate(t, y) == pytest.approx(a, abs=2e-3)
    y = np.exp(0.2 * t) * np.sin(5.0 * t) + 5.0 * np.exp(-3.0 * t) * np.sin(17.0 * t)  # a fast transient
    assert peak_growth_rate(t[t > 2.0], y[t > 2.0], skip=0) == pytest.approx(0.2, abs=5e-3)
    with pytest.raises(ValueError, match="too few peaks"):
        peak_growth_rate(t[:300], np.sin(5.0 * t[:300]))
