"""Kicked runs of the cantilevered pipe conveying liquid (open ends on the coupled tube, docs/theory.md §13) at 0.93
and 1.07 of its flutter threshold u_cr(beta) from varint.exact.pipe_stability (Païdoussis eq. 3.70, independent truth),
for the mass ratios beta of the issue: the run's growth rate (log-linear fit of the tip's peaks) against
varint.analysis.flowing_modes' (a cross-check).  The pipe of tests/test_coupled_open_ends.py (EI = 1, L = 1, M + m = 1,
inextensible rod, 20 elements) at that beta.  Numbers in docs/validation.md.

    python scripts/cantilever_pipe_runs.py [--betas 0.1,0.2,0.5,0.8] [--h 1.8e-3] [--periods 8] [--parcels-per-element 2]
"""

import argparse

import numpy as np

from varint.exact import pipe_stability as ps
from varint.analysis.signals import peak_growth_rate
from varint.errors import VarintError
from varint.model.model import build_model
from varint.analysis.modes import scene_modes
from varint.scene.standard import pipe_scene_text
from varint.scene.schema import parse_scene
from varint.run.simulation import Simulation

ENDS = ("clamped", "free")


def tip_history(scene, T):
    """Step for T seconds: times and the tip's lateral displacement at each level."""
    sim = Simulation(build_model(scene))
    n = int(round(T / sim.h))
    t, y = np.empty(n), np.empty(n)
    for i in range(n):
        sim.step()
        t[i], y[i] = sim.state.t, sim.fields()["rod/r"][-1, 1]
    return t, y


def modes_rate(beta, u, nodes):
    """The largest growth rate of varint.analysis.flowing_modes on the same lattice (the nearly inextensible rod)."""
    d = scene_modes(parse_scene(pipe_scene_text(ENDS, beta, u, nodes, constraint="none")), count=6)
    return max(m["growth_rate"] for m in d["modes"])


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--betas", default="0.1,0.2,0.5,0.8")
    ap.add_argument("--h", type=float, default=1.8e-3, help="largest step (smaller where the inflow would move more "
                    "than 0.4 parcel lengths per step)")
    ap.add_argument("--periods", type=float, default=8.0, help="run length in flutter periods 2 pi / omega_cr")
    ap.add_argument("--parcels-per-element", type=int, default=2, help="fluid parcels per rod element (two: one lets "
                    "the labels passing the nodes pump lattice modes at the fast flows of beta = 0.5, 0.8, "
                    "docs/theory.md §12)")
    a = ap.parse_args()
    print("| beta | u_cr (pipe_stability) | u/u_cr | h [s] | run's rate [1/s] | flowing_modes' rate [1/s] | outcome |")
    print("|---|---|---|---|---|---|---|")
    for beta in [float(b) for b in a.betas.split(",")]:
        u_c, w_c, kind = ps.critical_flow_velocity(beta, "clamped-free")
        for frac in (0.93, 1.07):
            U = frac * u_c / np.sqrt(beta)
            ppe = a.parcels_per_element
            h = float(min(a.h, 0.4 * (1.0 / (20 * ppe)) / U))
            scene = parse_scene(pipe_scene_text(ENDS, beta, frac * u_c, 21, constraint="inextensible_unshearable",
                                                parcels=20 * ppe, h=h, kick=1e-3))
            try:
                t, y = tip_history(scene, a.periods * 2 * np.pi / w_c)
                rate = peak_growth_rate(t, y)
                ok = "decays" if rate < 0 else "grows"
            except (VarintError, ValueError) as exc:
                rate, ok = float("nan"), f"failed: {str(exc).splitlines()[0][:60]}"
            ref = modes_rate(beta, frac * u_c, 21)
            print(f"| {beta} | {u_c:.4f} ({kind}) | {frac} | {h:.3g} | {rate:+.3f} | {ref:+.3f} | {ok} |", flush=True)


if __name__ == "__main__":
    main()
