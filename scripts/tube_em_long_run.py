"""A long run of the coupled tube's energy-momentum step (varint/schemes/em_tube.py, docs/theory.md §12b, §12c): the free
spinning hose of examples/whirling_hose_energy_momentum.toml (water flowing at 1 m/s, dynamic wall, 12 elements,
h = 10 ms, where the midpoint step stops within 35 steps), for --steps steps.  Every --every steps: the energy error
relative to the initial kinetic energy, the momenta's changes relative to |J0|, the labels' constraint and the
liquid's volume residual, the directors' share of the kinetic energy (the unresolved rotational modes, §12c) and the
steps Newton could only solve through two half steps; at the end the maxima and whether the energy error grows (a
least-squares slope of |dE| against time).

--nodes N runs the same hose on N nodes (N - 1 parcels).  --save FILE writes the step's state (and the reference
E0, K0, P0, J0) to FILE (.npz) every --every steps (and drops Newton's kept factorisation there, as a resumed run
starts without one, so that the pieces are one run bit for bit); --resume FILE continues such a run where it stopped:
a run of 10^5 steps (~1.5 h at 12 elements on one core since the compiled loops; 2.5-3 h before) can be made in
pieces.  Newton's counts (iterations, Jacobians, steps solved through halves) are those of the piece.

Run: OPENBLAS_NUM_THREADS=1 python scripts/tube_em_long_run.py [--steps 20000] [--every 100] [--nodes 13]
         [--save run.npz] [--resume run.npz]
"""

from __future__ import annotations

import argparse
import re
import time
from pathlib import Path

import numpy as np

from varint import build_model, load_scene, parse_scene
from varint.schemes.em_tube import TubeEMStep

SCENE = Path(__file__).resolve().parent.parent / "examples" / "whirling_hose_energy_momentum.toml"


def hose(nodes):
    """The example's hose on ``nodes`` nodes (nodes - 1 parcels)."""
    if nodes == 13:
        return build_model(load_scene(str(SCENE)))
    text, k1 = re.subn(r"(?m)^nodes = 13$", f"nodes = {nodes}", SCENE.read_text())
    text, k2 = re.subn(r"(?m)^parcels = 12$", f"parcels = {nodes - 1}", text)
    if (k1, k2) != (1, 1):
        raise SystemExit(f"{SCENE.name} no longer has the lines 'nodes = 13' and 'parcels = 12' this script changes")
    return build_model(parse_scene(text))


def director_share(st):
    """The directors' kinetic energy 1/2 sum E_ji |d_ji'|^2 (the frames' rotary inertia) over the total kinetic energy."""
    return 0.5 * float(np.sum(st.E[:, None, :] * st.V ** 2)) / st.kinetic_energy()


def save(path, st, ref):
    np.savez(path, n=st.n, **ref, **st.state_data())


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=20000, help="the run's last step (a resumed run: counted from 0)")
    ap.add_argument("--every", type=int, default=100)
    ap.add_argument("--nodes", type=int, default=13)
    ap.add_argument("--save", default=None)
    ap.add_argument("--resume", default=None)
    a = ap.parse_args()
    model = hose(a.nodes)
    st = TubeEMStep(model, model.scene.time.step)
    if a.resume:
        data = dict(np.load(a.resume))
        ref = {k: data.pop(k) for k in ("E0", "K0", "P0", "J0")}
        st.restore(data, int(data.pop("n")))
    else:
        ref = dict(E0=st.energy(), K0=st.kinetic_energy(), P0=st.linear_momentum(), J0=st.angular_momentum())
    E0, K0, P0, J0 = (ref[k] for k in ("E0", "K0", "P0", "J0"))
    if st.n >= a.steps:
        raise SystemExit(f"--steps {a.steps}: the run is already at step {st.n}")
    sJ = np.linalg.norm(J0)
    rows, t0, n_start = [], time.perf_counter(), st.n
    print(f"# {a.nodes} nodes, h = {st.h:g} s, steps {n_start + 1}..{a.steps}")
    print("| step | t [s] | (E - E0)/K0 | max dP L/abs(J0) | max dJ/abs(J0) | label constraint | volume residual | "
          "directors' share of K | steps by halves | wall s |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    while st.n < a.steps:
        st.step()
        n = st.n
        if n % a.every == 0 or n == a.steps:
            m = st.monitors()
            row = (n, n * st.h, (m["energy"] - E0) / K0, float(np.abs(m["linear_momentum"] - P0).max()) * model.L / sJ,
                   float(np.abs(m["angular_momentum"] - J0).max()) / sJ, m["label_constraint"],
                   m.get("constraint_residual", 0.0), director_share(st), st.stats.get("halvings", 0),
                   time.perf_counter() - t0)
            rows.append(row)
            print("| %d | %.1f | %.2e | %.1e | %.1e | %.1e | %.1e | %.1e | %d | %.0f |" % row, flush=True)
            if a.save:
                save(a.save, st, ref)
                st._lu = None  # as a resumed run starts: the pieces of a saved run are then one run, bit for bit
    R = np.array(rows)
    slope = np.polyfit(R[:, 1], np.abs(R[:, 2]), 1)[0] if len(R) > 1 else float("nan")
    steps = st.n - n_start
    print(f"\nmax abs(dE)/K0 {np.abs(R[:, 2]).max():.2e}, slope of abs(dE)/K0 per simulated second {slope:.1e}; "
          f"max dP {R[:, 3].max():.1e}, dJ {R[:, 4].max():.1e}; {R[-1, 9] / steps * 1e3:.1f} ms/step "
          f"({st.stats['iterations'] / steps:.1f} iterations, {st.stats['jacobians'] / steps:.2f} Jacobians per step); "
          f"steps solved through halves: {st.stats.get('halvings', 0)} (of which kept as two half steps: "
          f"{st.stats.get('halved_steps', 0)})")


if __name__ == "__main__":
    main()
