"""How accurate the energy-momentum step is on the motion of §12's base case (docs/theory.md §12a).

PyElastica's section, free arc kappa = 2 /m spinning at 2 rad/s about z, N = 50, 3D model, T = 1 s.  Reference: the
midpoint scheme at h = 0.25 ms (h omega_max = 1.5: resolved, below every resonance window of §12 A).  For the
energy-momentum step at several h and the midpoint at the same h: the error of the node positions at T (max over the
nodes, relative to L), the energy error, and how the run ended.

Run: python scripts/rod_em_accuracy.py   (about 3 min)
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from rod_stiff_diagnosis import make  # noqa: E402

from varint import Simulation  # noqa: E402
from varint.errors import SolverError  # noqa: E402
from varint.terms.rod import unpack_level  # noqa: E402
from varint.schemes.em_rod import RodEMStep  # noqa: E402

T = 1.0


def midpoint_positions(h):
    sim = Simulation(make(h=h, dim=3), h=h)
    E0 = sim.monitors()["energy"]
    k = int(round(T / h))
    for n in range(k):
        try:
            sim.step()
        except SolverError:
            return None, f"fails at step {n + 1}", np.nan
        e = sim.monitors()["energy"] / E0 - 1
        if abs(e) > 10:
            return None, f"explodes at step {n + 1}", e
    _, r, o = unpack_level(sim.state.q[sim.model.rod_q], sim.model.rod.N)
    return r + o, "runs", e


def em_positions(h):
    s = RodEMStep(make(h=h, dim=3), h)
    E0 = s.energy()
    for _ in range(int(round(T / h))):
        s.step()
    return s.r + s.origin, "runs", s.energy() / E0 - 1


def main():
    ref, _, _ = midpoint_positions(2.5e-4)
    print("| h [ms] | energy-momentum: position error at T / L | energy error | midpoint: position error / L | outcome |")
    print("|---|---|---|---|---|")
    for h in (8e-3, 5e-3, 4e-3, 2e-3, 1e-3):
        r, _, e = em_positions(h)
        rm, om, _ = midpoint_positions(h)
        em_err = np.max(np.linalg.norm(r - ref, axis=1))
        mp = f"{np.max(np.linalg.norm(rm - ref, axis=1)):.1e}" if rm is not None else "-"
        print(f"| {h * 1e3:g} | {em_err:.1e} | {e:.1e} | {mp} | {om} |", flush=True)


if __name__ == "__main__":
    main()
