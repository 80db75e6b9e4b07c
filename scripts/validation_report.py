"""Measure every validation case of tests/ and print the numbers recorded in docs/validation.md.

The tests assert tolerances; this script reports the measured errors.  Run:
    python scripts/validation_report.py
"""

import math

import numpy as np

from varint import Simulation, build_model
from varint.analysis.linear import modes
from varint.analysis.signals import dominant_wavenumber_index, observed_orders
from varint.exact.waves import dispersion_branches, webster_frequencies
from varint.scene.standard import AIR, AIR_SOUND_SPEED as C0, gas_scene, scene_of

from _runs import gas_final_state, gas_observables, standing_wave_frequency


def sound_speed():
    out = []
    for scheme in ("midpoint", "trapezoidal"):
        k = 2 * math.pi
        pert = [{"field": "pressure", "shape": "cosine", "amplitude": 10.0, "wavelength": 1.0}]
        model = build_model(scene_of(gas_scene(nodes=65, parcels=64, wall=False, ends="periodic", h=2e-6, perturbation=pert,
                                               scheme=scheme)))
        sim = Simulation(model)
        om = standing_wave_frequency(model, sim, int(3.2 * 2 * math.pi / (C0 * k) / 2e-6), k)
        out.append(f"| sound speed, rigid periodic tube, 64 parcels/λ, {scheme} | √(γp/ρ) = {C0:.4f} m/s | {om / k:.4f} m/s | {om / k / C0 - 1:+.2e} |")
    return out


def dispersion():
    model = build_model(scene_of(gas_scene(nodes=129, parcels=128, ends="periodic")))
    m = model.tube  # the s, R blocks; the mode shapes are in its inertial unknowns
    res, X = modes(m, count=m.nq, vectors=True)
    freq = np.array([r["frequency"] for r in res])
    idx = np.array([dominant_wavenumber_index(X[m.layout["R"], i]) for i in range(X.shape[1])])
    w = m.wall
    out = []
    for j in (1, 2, 3, 4):
        k = 2 * math.pi * j
        lo, hi = dispersion_branches(k, C0, AIR["density"], m.R0, w.a, w.beta1, w.beta2)
        f = np.sort(freq[(idx == j) & (freq > 1.0)])
        out.append(f"| dispersion, low branch, k = 2π·{j}/m, 128 nodes/m (modes) | ω = {lo:.2f} rad/s | {f[0]:.2f} | {f[0] / lo - 1:+.2e} |")
        out.append(f"| dispersion, high branch, k = 2π·{j}/m (modes) | ω = {hi:.2f} rad/s | {f[2]:.2f} | {f[2] / hi - 1:+.2e} |")
    return out


def moens_korteweg():
    E, hw, R0, rho = 4e5, 1e-3, 0.01, 1050.0
    c = math.sqrt(E * hw / (2 * rho * R0))
    k = 2 * math.pi
    d = {"title": "MK", "tube": {"length": 1.0, "nodes": 65, "radius": R0},
         "wall": {"model": "quasistatic", "law": "tube-law", "thickness": hw, "youngs_modulus": E, "poisson_ratio": 0.0},
         "fluid": {"model": "incompressible", "density": rho, "pressure": 0.0, "parcels": 64, "ends": {"s0": "periodic", "sL": "periodic"},
                   "perturbation": [{"field": "velocity", "shape": "cosine", "amplitude": 1e-3, "wavelength": 1.0}]},
         "environment": {"external_pressure": 0.0}, "time": {"step": 2e-4, "end": 1.0}}
    model = build_model(scene_of(d))
    sim = Simulation(model)
    om = standing_wave_frequency(model, sim, int(2.2 * 2 * math.pi / (c * k) / 2e-4), k, field="velocity")
    return [f"| Moens–Korteweg, liquid, tube law, a = 0, 64 parcels/λ | √(Eh/2ρR₀) = {c:.4f} m/s | {om / k:.4f} m/s | {om / k / c - 1:+.2e} |"]


def webster():
    L, A0 = 1.0, 1e-3
    area = lambda s: A0 * math.exp(2.0 * s)  # noqa: E731
    xs = np.linspace(0.0, L, 401)
    d = {"title": "horn", "tube": {"length": L, "nodes": 201, "radius": 0.02, "area_table": [[float(x), area(x)] for x in xs]},
         "fluid": dict(AIR, parcels=200), "time": {"step": 1e-5, "end": 1e-3}}
    model = build_model(scene_of(d))
    fm = np.array([r["frequency"] for r in modes(model, count=4)])
    fw = webster_frequencies(area, L, C0, count=4)
    return [f"| Webster horn A = A₀e^{{2s}}, closed, mode {i + 1}, 200 parcels | {b:.3f} rad/s (scipy shooting) | {a:.3f} | {a / b - 1:+.2e} |"
            for i, (a, b) in enumerate(zip(fm, fw))]


def orders():
    out = []
    T = 2e-3
    for scheme in ("midpoint", "trapezoidal"):
        rm, r = gas_final_state(16, T / 1280, T, scheme)
        ro = gas_observables(rm, r)
        errs = [np.max(np.abs(gas_observables(*gas_final_state(16, T / n, T, scheme)) - ro)) for n in (40, 80, 160)]
        o = observed_orders(errs)
        out.append(f"| order in h, {scheme}, h = T/40, T/80, T/160 | 2 | errors {', '.join(f'{e:.2e}' for e in errs)} | orders {', '.join(f'{x:.3f}' for x in o)} |")
    for wall in (True, False):
        rm, r = gas_final_state(256, 2.5e-6, 1.5e-3, wall=wall)
        ro = gas_observables(rm, r)
        errs = [np.max(np.abs(gas_observables(*gas_final_state(M, 2.5e-6, 1.5e-3, wall=wall)) - ro)) for M in (16, 32, 64)]
        o = observed_orders(errs)
        out.append(f"| order in Δs, {'dynamic wall' if wall else 'rigid'}, 16/32/64 parcels | 2 | errors {', '.join(f'{e:.2e}' for e in errs)} | orders {', '.join(f'{x:.3f}' for x in o)} |")
    return out


if __name__ == "__main__":
    print("| case | truth | varint | relative error |\n|---|---|---|---|")
    for f in (sound_speed, dispersion, moens_korteweg, webster):
        for line in f():
            print(line, flush=True)
    print("\n| convergence | declared | measured | observed |\n|---|---|---|---|")
    for line in orders():
        print(line, flush=True)
