"""A garden hose in large free motion: the coupled tube (rod + wall + fluid) with the energy-momentum step
(varint/schemes/em_tube.py, docs/theory.md §12b) against the midpoint step at steps set by the motion.

The hose: rubber annulus (outer radius 12 mm, bore 10 mm, E = 5 MPa, rho = 1100 kg/m^3), 1 m, free, released from an
arc (curvature 2/m about z and 1/m about y) while spinning at 2 rad/s about z; water (incompressible, or barotropic with
a 2.2 GPa bulk modulus) or air (ideal gas, 1 bar) flowing at 1 m/s relative to the hose; a dynamic linear wall (2 mm
of the same rubber).  Its first free-free bending period is about 0.9 s; its stiffest lattice modes (shear-rotation,
axial) have h omega of 10-40 at h = 5-10 ms.  For each fluid and step: how far each scheme runs, the largest energy
change relative to the initial kinetic energy, the momenta's largest change relative to |J0|, Newton iterations and
wall time per step (the machine's load included: not a timing).

Run: python scripts/tube_em_hard_cases.py [--steps 2000] [--steps-list 0.005,0.01] [--fluids liquid,air] [--nodes 21]
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from varint import Simulation, build_model, parse_scene
from varint.errors import SolverError
from varint.scene.text import to_toml

E_RUBBER, RHO_RUBBER, NU = 5.0e6, 1100.0, 0.45


def hose_section(outer=0.012, bore=0.010):
    A = math.pi * (outer ** 2 - bore ** 2)
    I = math.pi / 4 * (outer ** 4 - bore ** 4)
    G = E_RUBBER / (2 * (1 + NU))
    return dict(mass_per_length=RHO_RUBBER * A, rotary_inertia=RHO_RUBBER * I, bending_stiffness=E_RUBBER * I,
                torsional_stiffness=G * 2 * I, axial_stiffness=E_RUBBER * A, shear_stiffness=0.5 * G * A)


FLUIDS = {
    "liquid": dict(model="incompressible", density=1000.0, pressure=1.0e5),
    "barotropic": dict(model="barotropic", density=1000.0, pressure=1.0e5, bulk_modulus=2.2e9),
    "air": dict(model="ideal-gas", gamma=1.4, density=1.2, pressure=1.0e5),
}


def scene(fluid, h, nodes=21, scheme="midpoint", end=1.0, wall=True):
    d = {"title": f"hose {fluid}", "tube": {"length": 1.0, "nodes": nodes, "radius": 0.010},
         "rod": dict(hose_section(), dimension=3, ends={"s0": "free", "sL": "free"},
                     initial={"curvature": [0.0, 1.0, 2.0], "angular_velocity": [0.0, 0.0, 2.0]}),
         "fluid": dict(FLUIDS[fluid], parcels=nodes - 1, velocity=1.0),
         "time": {"step": h, "end": end, "scheme": scheme}}
    if wall:
        d["wall"] = {"model": "dynamic", "law": "linear", "thickness": 2.0e-3, "density": RHO_RUBBER,
                     "youngs_modulus": E_RUBBER, "poisson_ratio": NU}
    return build_model(parse_scene(to_toml(d)))


def run(model, steps, blow=1.0):
    """Step a Simulation; returns (steps run, max |dE|/K0, max |dP| L/|J0|, max |dJ|/|J0|, it/step, s/step, outcome)."""
    sim = Simulation(model)
    m0 = sim.monitors()
    E0, K0, P0, J0 = m0["energy"], m0["kinetic_energy"], m0["linear_momentum"], m0["angular_momentum"]
    sJ = np.linalg.norm(J0)
    dE = dP = dJ = 0.0
    its, t0, outcome, n = 0, time.perf_counter(), "runs", 0
    for n in range(1, steps + 1):
        try:
            sim.step()
        except SolverError as exc:
            outcome = f"stops at step {n}: {str(exc)[:60]}"
            n -= 1
            break
        mon = sim.monitors()
        its += sim.stats.iterations
        dE = max(dE, abs(mon["energy"] - E0) / K0)
        dP = max(dP, float(np.max(np.abs(mon["linear_momentum"] - P0))) * model.L / sJ)
        dJ = max(dJ, float(np.max(np.abs(mon["angular_momentum"] - J0))) / sJ)
        if not np.isfinite(mon["energy"]) or dE > blow:
            outcome = f"explodes at step {n} (|dE| > {blow} K0)"
            break
    wall = time.perf_counter() - t0
    return n, dE, dP, dJ, its / max(n, 1), wall / max(n, 1), outcome


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--steps-list", default="0.005,0.01")
    ap.add_argument("--fluids", default="liquid,air")
    ap.add_argument("--nodes", type=int, default=21)
    ap.add_argument("--schemes", default="midpoint,energy-momentum")
    a = ap.parse_args()
    print("| fluid | h [ms] | scheme | steps run | max abs(dE)/K0 | max dP L/abs(J0) | max dJ/abs(J0) | Newton it./step | s/step | outcome |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for fluid in a.fluids.split(","):
        for h in map(float, a.steps_list.split(",")):
            for scheme in a.schemes.split(","):
                model = scene(fluid, h, a.nodes, scheme, end=a.steps * h)
                n, dE, dP, dJ, it, sps, outcome = run(model, a.steps)
                print(f"| {fluid} | {1e3 * h:g} | {scheme} | {n} | {dE:.1e} | {dP:.1e} | {dJ:.1e} | {it:.1f} | {sps:.3f} | "
                      f"{outcome} |", flush=True)


if __name__ == "__main__":
    main()
