"""varint's Cayley-map midpoint rod against PyElastica's PositionVerlet, side by side in one run.

Case (PyElastica's cantilever benchmark section): cantilever L = 1 m, solid radius 1 cm, rho = 1000 kg/m^3, E = 1e6 and 1e7 Pa,
G = E/1.5, 100 elements, released from the first Euler-Bernoulli mode shape with a 1 cm tip
deflection, no damping.  Reported per tool and step size: wall time for 10 first-mode periods, the
error of the tip trajectory against the analytic first-mode motion 0.01 cos(omega_T t) (omega_T: the
Timoshenko first frequency, scipy), the energy deviation, and the first frequency measured from the
tip signal.  Also the largest stable PyElastica step (bisection on short runs).

PyElastica is an optional comparison tool, not a dependency:  pip install -e '.[compare]'
Run:  python scripts/bench_pyelastica.py [--quick]
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import numpy as np

from varint import Simulation, build_model, parse_scene
from varint.analysis.signals import zero_crossing_frequency
from varint.exact.beams import EULER_BERNOULLI_CLAMPED_FREE, timoshenko_cantilever
from varint.lattice.lie import cay
from varint.scene.standard import solid_section
from varint.scene.text import to_toml

ROOT = Path(__file__).resolve().parent.parent

L, RAD, RHO, N_EL, TIP = 1.0, 0.01, 1000.0, 100, 0.01


def mode_shape(s):
    """First clamped-free Euler-Bernoulli mode, scaled to a TIP deflection, and its slope."""
    b = EULER_BERNOULLI_CLAMPED_FREE[0] / L
    sg = (math.cosh(b * L) + math.cos(b * L)) / (math.sinh(b * L) + math.sin(b * L))
    phi = lambda x: np.cosh(b * x) - np.cos(b * x) - sg * (np.sinh(b * x) - np.sin(b * x))  # noqa: E731
    dphi = lambda x: b * (np.sinh(b * x) + np.sin(b * x) - sg * (np.cosh(b * x) - np.cos(b * x)))  # noqa: E731
    return TIP * phi(s) / phi(L), TIP * dphi(s) / phi(L)


def reference(E):
    sec = solid_section(E, RAD, RHO)
    return timoshenko_cantilever(sec["bending_stiffness"], sec["shear_stiffness"], sec["mass_per_length"],
                                 sec["rotary_inertia"], L, count=1)[0]


# ----------------------------------------------------------------------------- varint


def varint_cantilever(E, h, n_el=N_EL):
    """The planar varint model of the cantilever at n_el elements and step h, released from the mode shape."""
    sec = solid_section(E, RAD, RHO)  # the same section as the tests' PyElastica benchmark rod
    d = {"title": "cantilever", "tube": {"length": L, "nodes": n_el + 1, "radius": RAD},
         "rod": dict(sec, dimension=2, measure="reference", ends={"s0": "clamped", "sL": "free"}),
         "time": {"step": h, "end": 1.0}}
    model = build_model(parse_scene(to_toml(d)))
    s = np.linspace(0.0, L, n_el + 1)
    y, dy = mode_shape(s)
    model.rod.set_configuration(cay(np.stack([np.zeros_like(s), np.zeros_like(s), 2 * np.tan(0.5 * np.arctan(dy))], axis=1)),
                            np.stack([s, y, np.zeros_like(s)], axis=1))
    return model


def varint_run(E, h, periods, w_ref):
    model = varint_cantilever(E, h)
    sim = Simulation(model)
    n = int(round(periods * 2 * math.pi / w_ref / h))
    t, tip, E_ = np.empty(n), np.empty(n), np.empty(n)
    t0 = time.perf_counter()
    for i in range(n):
        sim.step()
        t[i] = sim.state.t
        tip[i] = sim.state.q[model.rod_q][3 * N_EL + 1]  # y of the tip node (layout: varint.model.model)
        E_[i] = sim.monitors()["energy"]
    wall = time.perf_counter() - t0
    return t, tip, E_, wall, sim.stats.total_iterations / n


# ----------------------------------------------------------------------------- PyElastica


def pyelastica_cantilever(E, n_el=N_EL):
    """PyElastica's cantilever at n_el elements, released from the mode shape, finalised: (simulator, rod)."""
    import elastica as ea

    class Sim(ea.BaseSystemCollection, ea.Constraints):
        pass

    sim = Sim()
    rod = ea.CosseratRod.straight_rod(n_el, np.zeros(3), np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]), L, RAD, RHO,
                                      youngs_modulus=E, shear_modulus=E / 1.5)
    s = np.linspace(0.0, L, n_el + 1)
    y, _ = mode_shape(s)
    rod.position_collection[1, :] = y
    # directors: d3 along each element's chord, d1 = +z (out of plane), d2 = d3 x d1
    chord = np.diff(rod.position_collection, axis=1)
    d3 = chord / np.linalg.norm(chord, axis=0)
    d1 = np.zeros_like(d3)
    d1[2] = 1.0
    d2 = np.cross(d3.T, d1.T).T
    rod.director_collection[0] = d1
    rod.director_collection[1] = d2
    rod.director_collection[2] = d3
    sim.append(rod)
    sim.constrain(rod).using(ea.OneEndFixedBC, constrained_position_idx=(0,), constrained_director_idx=(0,))
    sim.finalize()
    return sim, rod


def pyelastica_stepper(E, dt, n_el=N_EL):
    """A function doing n PositionVerlet steps of dt on the cantilever at n_el elements, continuing from the last call
    (its kernels compiled by 200 steps first): the per-step timing loop of the benchmarks."""
    import elastica as ea

    sim, _ = pyelastica_cantilever(E, n_el)
    stepper = ea.PositionVerlet()
    clock = [0.0]

    def run(n):
        t = clock[0]
        for _ in range(n):
            t = stepper.step(sim, t, dt)
        clock[0] = t

    run(200)
    return run


def pyelastica_run(E, dt, periods, w_ref, check_only_steps=None, n_el=N_EL):
    import elastica as ea

    sim, rod = pyelastica_cantilever(E, n_el)
    stepper = ea.PositionVerlet()
    n = check_only_steps or int(round(periods * 2 * math.pi / w_ref / dt))
    every = max(1, n // 4000)
    ts, tips, Es = [], [], []
    energy = lambda: (rod.compute_translational_energy() + rod.compute_rotational_energy()  # noqa: E731
                      + rod.compute_bending_energy() + rod.compute_shear_energy())
    tcur = 0.0
    t0 = time.perf_counter()
    for i in range(n):
        tcur = stepper.step(sim, tcur, dt)
        if check_only_steps is None and i % every == 0:
            ts.append(tcur)
            tips.append(rod.position_collection[1, -1])
            Es.append(energy())
    wall = time.perf_counter() - t0
    if check_only_steps is not None:
        return bool(np.all(np.isfinite(rod.position_collection)) and np.max(np.abs(rod.position_collection[1])) < 0.1)
    # the wall time includes the energy sampling (about 0.1 s of 40 s at 100 elements: 4000 calls of ~21 µs);
    # scripts/work_precision_pyelastica.py times the stepping alone
    return np.array(ts), np.array(tips), np.array(Es), wall


def largest_stable_dt(E, w_ref, lo=1e-6, hi=1e-3, steps=3000, n_el=N_EL):
    for _ in range(12):
        mid = math.sqrt(lo * hi)
        if pyelastica_run(E, mid, 0, w_ref, check_only_steps=steps, n_el=n_el):
            lo = mid
        else:
            hi = mid
    return lo


def summarise(t, tip, E, w_ref):
    err = np.max(np.abs(tip - TIP * np.cos(w_ref * t))) / TIP
    dE = np.max(np.abs(E - E[0])) / abs(E[0])
    w = zero_crossing_frequency(t, tip)
    return err, dE, w / w_ref - 1


def plot(rows_by_E, path):
    """Work-precision: tip error against wall time per simulated second, one panel per E."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(rows_by_E), figsize=(5.5 * len(rows_by_E), 4.2), constrained_layout=True, squeeze=False)
    for ax, (E, rows) in zip(axes[0], rows_by_E.items()):
        for name, marker in (("varint midpoint", "o-"), ("PyElastica PositionVerlet", "s-")):
            pts = sorted((r[4], r[5]) for r in rows if r[0] == name)
            if pts:
                ax.loglog([p[0] for p in pts], [p[1] for p in pts], marker, label=name)
        ax.set_xlabel("wall s per simulated s")
        ax.set_ylabel("tip error / amplitude over 10 periods")
        ax.set_title(f"cantilever, 100 elements, E = {E:.0e} Pa", fontsize=9)
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
    fig.savefig(path, dpi=110)


def main(quick=False):
    periods = 2 if quick else 10
    print(f"### Cantilever, {N_EL} elements, {periods} first-mode periods (tip error against 0.01 cos(omega_T t))\n")
    print("| E [Pa] | tool | step [s] | steps/period | wall s | wall s per simulated s | tip error / amplitude | max energy dev. | 1st freq. error vs Timoshenko |")
    print("|---|---|---|---|---|---|---|---|---|")
    rows_by_E = {}
    for E in (1e6, 1e7):
        w = reference(E)
        T1 = 2 * math.pi / w
        try:
            dt_max = largest_stable_dt(E, w)
        except ImportError:
            dt_max = None
        rows = []
        for k in ((16, 32) if quick else (16, 32, 64, 128)):
            t, tip, En, wall, its = varint_run(E, T1 / k, periods, w)
            err, dE, fe = summarise(t, tip, En, w)
            rows.append(("varint midpoint", T1 / k, k, wall, wall / (periods * T1), err, dE, fe))
        if dt_max is not None:
            for frac in ((0.5,) if quick else (0.5, 0.25)):
                dt = frac * dt_max
                t, tip, En, wall = pyelastica_run(E, dt, periods, w)
                err, dE, fe = summarise(t, tip, En, w)
                rows.append(("PyElastica PositionVerlet", dt, T1 / dt, wall, wall / (periods * T1), err, dE, fe))
        rows_by_E[E] = rows
        for name, dt, k, wall, rate, err, dE, fe in rows:
            print(f"| {E:.0e} | {name} | {dt:.3g} | {k:.0f} | {wall:.2f} | {rate:.3g} | {err:.2e} | {dE:.2e} | {fe:+.2e} |")
        if dt_max is not None:
            print(f"| {E:.0e} | PyElastica largest stable dt (bisection, 3000 steps) | {dt_max:.3g} | {T1 / dt_max:.0f} | | | | | |")
        print(f"| {E:.0e} | varint midpoint: no stability limit (linearly A-stable); step chosen for accuracy | | | | | | | |")
        sys.stdout.flush()
    if not quick:  # a quick check must not replace the documented plot with a 2-period one
        plot(rows_by_E, ROOT / "docs" / "rod_work_precision.png")


if __name__ == "__main__":
    main(quick="--quick" in sys.argv)
