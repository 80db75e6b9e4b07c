"""Where the energy of the coupled tube's energy-momentum step goes over long runs (docs/theory.md §12c): the hose of
examples/whirling_hose_energy_momentum.toml stepped for --time seconds at several steps h; every --every-time seconds
the directors' share of the kinetic energy (1/2 sum E_ji |d_ji'|^2, the frames' rotary inertia: the shear-rotation and
torsion modes, unresolved at h = 10 ms), the nodes' largest body angular velocity and the energy error.  If the share
grew alike at every h it would be the semi-discrete tube's own dynamics; growing faster at larger h, it is the time
step's doing.

Run: OPENBLAS_NUM_THREADS=1 python scripts/tube_em_stiff_energy.py [--time 10] [--steps-list 0.01,0.005,0.0025]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from tube_em_long_run import director_share, hose  # noqa: E402

from varint.schemes.em_tube import TubeEMStep  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--time", type=float, default=10.0)
    ap.add_argument("--every-time", type=float, default=1.0)
    ap.add_argument("--steps-list", default="0.01,0.005,0.0025")
    ap.add_argument("--nodes", type=int, default=13)
    a = ap.parse_args()
    model = hose(a.nodes)
    hs = [float(x) for x in a.steps_list.split(",")]
    marks = np.arange(1, int(round(a.time / a.every_time)) + 1) * a.every_time
    table = {}
    for h in hs:
        st = TubeEMStep(model, h)
        E0, K0 = st.energy(), st.kinetic_energy()
        rows, t0 = [(0.0, director_share(st), np.abs(st.body_angular_velocity()).max(), 0.0)], time.perf_counter()
        every = int(round(a.every_time / h))
        for n in range(1, len(marks) * every + 1):
            st.step()
            if n % every == 0:
                rows.append((n * h, director_share(st), float(np.abs(st.body_angular_velocity()).max()),
                             (st.energy() - E0) / K0))
        table[h] = rows
        print(f"# h = {h:g} s: {len(marks) * every} steps in {time.perf_counter() - t0:.0f} s, "
              f"{st.stats.get('halvings', 0)} solved through halves", flush=True)
    print("\n| t [s] | " + " | ".join(f"h = {h * 1e3:g} ms: directors' share of K, max abs(W) [rad/s]" for h in hs)
          + " | max abs(dE)/K0 (all h) |")
    print("|---|" + "---|" * len(hs) + "---|")
    for i in range(len(marks) + 1):
        cells = [f"{table[h][i][1]:.2e}, {table[h][i][2]:.0f}" for h in hs]
        dE = max(abs(table[h][i][3]) for h in hs)
        print(f"| {table[hs[0]][i][0]:g} | " + " | ".join(cells) + f" | {dE:.1e} |")


if __name__ == "__main__":
    main()
