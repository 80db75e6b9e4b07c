"""The momenta of the general Step path over long runs (docs/theory.md §9a, §10.6, "Momenta to round-off").

Run:  python scripts/general_momenta_roundoff.py [--steps 2000] [--case rod2d rod3d gas gas-g liquid] [--no-polish]

Cases: the constrained (inextensible, unshearable) free rod of scripts/rod_constraint_hard_cases.py (base case,
planar and 3D arc, midpoint, h = 5 ms), and the free gas-filled coupled tube of varint.scene.standard.COUPLED_CASES
("gas-rigid-free-3d", 9 nodes, 12 parcels, h = 1 ms) without gravity, and with it (then P changes by exactly
h M_tot g per step: the change from P0 + n h M_tot g is reported, and J.g), and its "liquid-rigid-free" (a liquid
held at the levels, theory §10.12).  All step through Simulation._solve (the general Step path).
Prints the largest changes over the run of P (times L) and J, relative to |J0|; with gravity the linear momentum's
change from P0 + n h M_tot g and J's component along g.  --no-polish: Simulation.rigid_polish = False.
"""

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from rod_stiff_diagnosis import make  # noqa: E402

from varint import Simulation, build_model  # noqa: E402
from varint.scene.standard import COUPLED_CASES, coupled_scene  # noqa: E402


def model_of(case):
    if case.startswith("rod"):
        kw = dict(dim=3, curvature=(0, 1.0, 2.0)) if case == "rod3d" else {}
        return make(h=5e-3, constraint="inextensible_unshearable", **kw), 5e-3
    name = "liquid-rigid-free" if case == "liquid" else "gas-rigid-free-3d"
    kw = {k: v for k, v in COUPLED_CASES[name].items() if k != "gravity" or case == "gas-g"}
    return build_model(coupled_scene(nodes=9, parcels=12, **kw)), 1e-3


def run(case, steps, polish=True):
    model, h = model_of(case)
    sim = Simulation(model, h=h)
    assert sim.scheme.name == "midpoint" and sim.stepper.compiled is None
    if hasattr(sim, "rigid_polish"):  # (absent before the polish: the script also measures older commits)
        sim.stepper.rigid_polish = polish
    m0 = sim.monitors()
    P0, J0, E0 = np.asarray(m0["linear_momentum"]), np.asarray(m0["angular_momentum"]), m0["energy"]
    g = np.asarray(model.rod.g, dtype=float)
    Mtot = float(np.sum(model.rod.node_mass)) + (float(np.sum(model.tube.label_mass_all)) if model.tube is not None else 0.0)
    gh = g / np.linalg.norm(g) if np.any(g) else None
    scale = np.linalg.norm(J0)
    dP = dJ = dE = 0.0
    its = 0
    t0 = time.perf_counter()
    for n in range(1, steps + 1):
        sim.step()
        its += sim.stats.iterations
        mo = sim.monitors()
        P = np.asarray(mo["linear_momentum"]) - P0 - n * h * Mtot * g
        J = np.asarray(mo["angular_momentum"]) - J0
        if gh is not None:
            J = np.array([J @ gh])
        dP = max(dP, float(np.abs(P).max()) * model.rod.L / scale)
        dJ = max(dJ, float(np.abs(J).max()) / scale)
        dE = max(dE, abs(mo["energy"] / E0 - 1.0))
    return dict(dP=dP, dJ=dJ, dE=dE, its=its / steps, wall=time.perf_counter() - t0)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--case", nargs="+", default=["rod2d", "rod3d", "gas", "gas-g", "liquid"])
    ap.add_argument("--no-polish", action="store_true")
    a = ap.parse_args()
    print("| case | steps | max dP L/abs(J0) | max dJ/abs(J0) | max abs(E/E0-1) | iterations/step | wall s |")
    print("|---|---|---|---|---|---|---|")
    for c in a.case:
        r = run(c, a.steps, polish=not a.no_polish)
        print(f"| {c} | {a.steps} | {r['dP']:.2g} | {r['dJ']:.2g} | {r['dE']:.3g} | {r['its']:.1f} | {r['wall']:.0f} |",
              flush=True)


if __name__ == "__main__":
    main()
