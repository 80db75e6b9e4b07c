"""The coupled energy-momentum step's Jacobian colouring (``TubeEMStep._plan``) against the number of elements.

A free hose of water in a rubber wall (one parcel per element), released bent and spinning: the CPU time of one
colouring of the Jacobian's pattern at the first step's predictor, and of the first and second steps.  The colouring
works on a sparse pattern of locations, so its cost grows like the number of locations (it was a dense boolean
product, O(locations^3): 0.78 s at 80 elements, 14 s at 160, 183 s at 320 on main at cba3494).

Run:  python scripts/bench_em_colouring.py [--elements 20,40,80,160,320]
Numbers: docs/performance.md ("The coupled energy-momentum step's colouring").
"""

from __future__ import annotations

import argparse
import time

from varint import build_model, parse_scene
from varint.scene.text import to_toml
from varint.schemes.em_tube import TubeEMStep


def hose(n):
    d = {"title": "hose", "tube": {"length": 1.0, "nodes": n + 1, "radius": 0.005},
         "rod": dict(mass_per_length=0.1, rotary_inertia=1e-6, bending_stiffness=0.01, torsional_stiffness=0.008,
                     axial_stiffness=100.0, shear_stiffness=80.0, dimension=3, ends={"s0": "free", "sL": "free"},
                     initial={"curvature": [0.0, 1.0, 0.0], "angular_velocity": [0.0, 0.0, 2.0]}),
         "fluid": {"model": "incompressible", "density": 1000.0, "parcels": n, "velocity": 1.0},
         "wall": {"model": "dynamic", "law": "linear", "thickness": 1e-3, "density": 1100.0, "youngs_modulus": 5e6},
         "time": {"step": 5e-3, "end": 1.0, "scheme": "energy-momentum"}}
    return build_model(parse_scene(to_toml(d)))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--elements", default="20,40,80,160,320")
    args = ap.parse_args()
    print("| elements | colouring s | colours | first step s | second step s |\n|---|---|---|---|---|")
    for n in map(int, args.elements.split(",")):
        st = TubeEMStep(hose(n), 5e-3)
        z = st._predict()
        t0 = time.process_time()
        _, nc, _, _ = st._plan(z)
        t1 = time.process_time()
        st._colouring.clear()
        st.step()
        t2 = time.process_time()
        st.step()
        t3 = time.process_time()
        print(f"| {n} | {t1 - t0:.3f} | {nc} | {t2 - t1:.3f} | {t3 - t2:.3f} |", flush=True)


if __name__ == "__main__":
    main()
