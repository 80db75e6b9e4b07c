"""Runs of the standard scenes (varint.scene.standard) that a test and a script share: the test runs them short and
asserts, the script runs them long or at more sizes and prints.  One definition for both, here (scripts import it as a
sibling; pytest puts scripts/ on sys.path, pyproject.toml).  Not a script: nothing runs on import.

* the closed rubber tube sloshing at 10 % (tests/test_conservation.py, scripts/slosh_long_run.py);
* the smooth wave's final state and the standing waves' frequency (tests/test_convergence.py, tests/test_waves.py,
  scripts/validation_report.py);
* the periodic flowing pipe's lateral wave (tests/test_flowing_pipe.py, scripts/flowing_pipe_linear.py);
* the spinning shaft's whirl and the spun free rod's flap (tests/test_rod_spinning.py, scripts/spinning_shaft_report.py).
"""

from __future__ import annotations

import math

import numpy as np

from varint import Simulation, build_model
from varint.analysis.rod_modes import rod_modes
from varint.analysis.signals import zero_crossing_frequency
from varint.model.statics import retract, static_equilibrium
from varint.scene.standard import (BLADE_SPIN, FLOWING_PIPE_K, FLOWING_PIPE_KICK, FLOWING_PIPE_STEP, blade_scene,
                                   periodic_pipe_scene, scene_of, shaft_scene, sloshing_scene, smooth_wave_scene)

# -- the closed rubber tube sloshing

#: relative energy-error bound of the 10 % sloshing run (measured 8.19e-10 over 10^4 and 10^5 steps, docs/validation.md)
BOUND_10PCT = 1.5e-9


def energy_series(sim, steps, every=10):
    """(times, energies) of a Simulation over ``steps`` steps, read every ``every`` steps."""
    E, t = [], []
    for n in range(steps):
        sim.step()
        if (n + 1) % every == 0:
            E.append(sim.monitors()["energy"])
            t.append(sim.state.t)
    return np.array(t), np.array(E)


def sloshing_record(steps, every=50):
    """Closed dynamic-wall tube, 10 % pressure sloshing, midpoint steps of h = 1e-5 s (~1.7e-3 s per wave period).

    At 20 % the wave steepens towards a shock within 10^5 steps and the energy error creeps
    (docs/validation.md); 10 % is nonlinear (harmonics, wall-fluid exchange) and stays smooth.
    Returns (simulation, times, relative energy errors, initial mass): the test suite's 10^4 steps
    (tests/test_conservation.py) and scripts/slosh_long_run.py's 10^5.
    """
    sim = Simulation(build_model(scene_of(sloshing_scene(1e-5, amplitude=0.1))))
    m0 = sim.monitors()["mass"]
    t, E = energy_series(sim, steps, every=every)
    return sim, t, (E - E[0]) / abs(E[0]), m0


# -- the smooth wave and standing waves in the gas-filled tube


def gas_final_state(parcels, h, T, scheme="midpoint", wall=True):
    """(model, simulation) of varint.scene.standard.smooth_wave_scene run to time T."""
    model = build_model(scene_of(smooth_wave_scene(parcels, h, scheme=scheme, wall=wall)))
    sim = Simulation(model)
    for _ in range(int(round(T / h))):
        sim.step()
    return model, sim


def gas_observables(model, sim, probes=(0.25, 0.5, 0.75)):
    """Positions of the labels that start at the probe points and radii at those nodes: present on every lattice."""
    cfg = model.tube.config(np.concatenate([sim.state.q, sim.state.lam]))
    M, N = model.tube.M, model.N
    out = [cfg.s[int(round(p * M))] for p in probes]
    if model.tube.has_wall:
        out += [cfg.R[int(round(p * N))] for p in probes]
    return np.array(out)


def standing_wave_frequency(model, sim, steps, k, field="pressure"):
    """Frequency of the projection of a fluid field (pressure or velocity) on cos(k x) over ``steps`` steps."""
    t, a = [], []
    for _ in range(steps):
        sim.step()
        f = sim.fields()
        s = f["fluid/s"]
        if field == "pressure":
            x, y = 0.5 * (s[1:] + s[:-1]), f["fluid/pressure"]
        else:
            x, y = s[:-1], f["fluid/velocity"][:-1]
        t.append(sim.state.t)
        a.append(np.sum((y - np.mean(y)) * np.cos(k * x)))
    return zero_crossing_frequency(np.array(t), np.array(a))


# -- the periodic flowing pipe


def periodic_pipe_run(U, nodes, parcels, steps=1200, h=FLOWING_PIPE_STEP, amplitude=FLOWING_PIPE_KICK):
    """Run varint.scene.standard.periodic_pipe_scene: the lateral Fourier coefficient c(t_n) of the rod at the
    kick's wavenumber, its magnitude, the energy error relative to the flow's kinetic energy, the largest lateral and
    axial momentum changes relative to the fluid's M U L, and the mean pressure less 1e5 Pa, step by step."""
    sim = Simulation(build_model(periodic_pipe_scene(U, nodes, parcels, steps, h, amplitude)))
    m0 = sim.monitors()
    c, energy, momentum, pressure = [], [], [], []
    for _ in range(steps):
        sim.step()
        f = sim.fields()
        r = f["rod/r"][:-1]  # node N is node 0's image
        c.append(np.mean(r[:, 1] * np.exp(-1j * FLOWING_PIPE_K * r[:, 0])))
        pressure.append(np.mean(f["fluid/pressure"]))
        mo = sim.monitors()
        energy.append(mo["energy"] - m0["energy"])
        momentum.append(np.asarray(mo["linear_momentum"]) - m0["linear_momentum"])
    scale = abs(m0["linear_momentum"][0])  # the fluid's, M U L
    momentum = np.abs(np.array(momentum)) / scale
    return {"c": np.array(c), "amplitude": np.abs(c), "energy": np.array(energy) / m0["energy_fluid_kinetic"],
            "momentum": momentum[:, 1].max(), "axial_momentum": momentum[:, 0].max(),
            "pressure": np.array(pressure) - 1e5}


# -- the spinning shaft and the spun free rod


def shaft_time_domain_whirl(nodes=21, h=1e-3, duration=3.0, amp=1e-4):
    """Release the spinning shaft (varint.scene.standard.shaft_scene) from a small planar bend in its first mode shape
    and fit the midpoint's complex deflection u = y + i z to a e^{i w1 t} + b e^{-i w2 t}: returns (w1, w2)."""
    from scipy.optimize import least_squares

    model = build_model(shaft_scene(nodes, h=h))
    s = model.rod.r0[:, 0]
    z = np.zeros((model.N + 1, 6))
    z[:, 1] = amp * np.sin(math.pi * s)  # y-deflection in the first mode shape ...
    z[:, 5] = amp * math.pi * np.cos(math.pi * s)  # ... with the sections turned with it
    model.rod.Lam0, model.rod.r0 = retract(model.rod.Lam0, model.rod.r0, z[model.rod.mask], model.rod.mask)
    sim = Simulation(model)
    mid = model.N // 2
    ts, us = [], []
    for _ in range(int(round(duration / h))):
        sim.step()
        r = sim.fields()["rod/r"][mid]
        ts.append(sim.state.t)
        us.append(r[1] + 1j * r[2])
    t, u = np.array(ts), np.array(us)

    def misfit(p):
        w1, w2 = p[:2]
        a, b = p[2] + 1j * p[3], p[4] + 1j * p[5]
        d = a * np.exp(1j * w1 * t) + b * np.exp(-1j * w2 * t) - u
        return np.concatenate([d.real, d.imag]) / amp

    # first guesses from the data alone: the peaks of the (zero-padded) spectrum at positive
    # (forward, in the sense of the spin) and negative (backward) frequency, then a least-squares fit
    spec = np.abs(np.fft.fft(u * np.hanning(len(u)), 16 * len(u)))
    freq = 2 * math.pi * np.fft.fftfreq(16 * len(u), h)
    g1 = freq[np.argmax(np.where(freq > 0, spec, 0))]
    g2 = -freq[np.argmax(np.where(freq < 0, spec, 0))]
    fit = least_squares(misfit, [g1, g2, amp / 2, 0, amp / 2, 0], x_scale=[10, 10, amp, amp, amp, amp])
    return fit.x[0], fit.x[1]


def blade_lattice_flap(nodes=41):
    """The spun free rod's (varint.scene.standard.blade_scene) lowest elastic flap frequency about its steady
    rotation (nearest to 67.5 rad/s), from the lattice's modes."""
    model = build_model(blade_scene(nodes))
    Lam, r, _ = static_equilibrium(model, spin=BLADE_SPIN)
    f = np.array([m["frequency"] for m in rod_modes(model, count=12, Lam=Lam, r=r)])
    return f[np.argmin(np.abs(f - 67.5))]


def blade_time_domain_flap(h, nodes=41, duration=1.0):
    """Release the spun rod from its steady rotation with a 0.1 mm out-of-plane bend in the free-free
    first mode shape; the tip's z(t) zero-crossing frequency (z is the spin axis, so out-of-plane
    motion is seen undistorted by the frame rotation)."""
    model = build_model(blade_scene(nodes, h=h))
    Lam, r, _ = static_equilibrium(model, spin=BLADE_SPIN)
    s = np.linspace(0.0, 1.0, model.N + 1)
    shape = np.cosh(4.73 * (s - 0.5)) / np.cosh(2.365) + np.cos(4.73 * (s - 0.5)) / np.cos(2.365)  # free-free mode 1
    z = np.zeros((model.N + 1, 6))
    z[:, 2] = 1e-4 * (shape - shape.mean())
    z[:, 4] = -1e-4 * np.gradient(shape, s)  # sections turned with the slope
    model.rod.set_configuration(*retract(Lam, r, z[model.rod.mask], model.rod.mask))
    sim = Simulation(model)
    t, tip = [], []
    for _ in range(int(round(duration / h))):
        sim.step()
        t.append(sim.state.t)
        tip.append(sim.fields()["rod/r"][-1, 2])
    return zero_crossing_frequency(np.array(t), np.array(tip))
