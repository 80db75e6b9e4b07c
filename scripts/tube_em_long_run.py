"""A long run of the coupled tube's energy-momentum step (varint/tube_em.py, docs/theory.md §12b): the free spinning hose
of examples/whirling_hose_energy_momentum.toml (water flowing at 1 m/s, dynamic wall, 12 elements, h = 10 ms, where
the midpoint step stops within 35 steps), for --steps steps.  Every --every steps: the energy error relative to the
initial kinetic energy, the momenta's changes relative to |J0|, the labels' constraint and the liquid's volume
residual; at the end the maxima and whether the energy error grows (a least-squares slope of |dE| against time).

Run: OPENBLAS_NUM_THREADS=1 python scripts/tube_em_long_run.py [--steps 20000] [--every 100]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from varint import build_model, load_scene
from varint.tube_em import TubeEMStep

SCENE = Path(__file__).resolve().parent.parent / "examples" / "whirling_hose_energy_momentum.toml"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=20000)
    ap.add_argument("--every", type=int, default=100)
    a = ap.parse_args()
    model = build_model(load_scene(str(SCENE)))
    st = TubeEMStep(model, model.scene.time.step)
    E0, K0, P0, J0 = st.energy(), st.kinetic_energy(), st.linear_momentum(), st.angular_momentum()
    sJ = np.linalg.norm(J0)
    rows, t0 = [], time.perf_counter()
    print("| step | t [s] | (E - E0)/K0 | max dP L/abs(J0) | max dJ/abs(J0) | label constraint | volume residual | wall s |")
    print("|---|---|---|---|---|---|---|---|")
    for n in range(1, a.steps + 1):
        st.step()
        if n % a.every == 0 or n == a.steps:
            m = st.monitors()
            row = (n, n * st.h, (m["energy"] - E0) / K0, float(np.abs(m["linear_momentum"] - P0).max()) * model.L / sJ,
                   float(np.abs(m["angular_momentum"] - J0).max()) / sJ, m["label_constraint"], m.get("constraint_residual", 0.0),
                   time.perf_counter() - t0)
            rows.append(row)
            print("| %d | %.1f | %.2e | %.1e | %.1e | %.1e | %.1e | %.0f |" % row, flush=True)
    R = np.array(rows)
    slope = np.polyfit(R[:, 1], np.abs(R[:, 2]), 1)[0]
    print(f"\nmax abs(dE)/K0 {np.abs(R[:, 2]).max():.2e}, slope of abs(dE)/K0 per simulated second {slope:.1e}; "
          f"max dP {R[:, 3].max():.1e}, dJ {R[:, 4].max():.1e}; {R[-1, 7] / a.steps * 1e3:.1f} ms/step "
          f"({st.stats['iterations'] / a.steps:.1f} iterations, {st.stats['jacobians'] / a.steps:.2f} Jacobians per step)")


if __name__ == "__main__":
    main()
