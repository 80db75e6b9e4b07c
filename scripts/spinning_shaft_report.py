"""The spinning-shaft validation of `varint modes` (gyroscopic matrix) and of the time-domain rod.

Prints the table recorded in docs/validation.md: whirl frequencies of a simply supported Timoshenko
shaft spinning at 60 rad/s (2.3 x its first critical speed), seen from the spinning frame, against
the continuum theory (varint.exact.beams.spinning_shaft_whirl), at 20 / 40 / 80 elements, with the observed
order; then the forward/backward whirl fitted to a time-domain run, and the flap frequency of the
spun free rod in the time domain against its modes.  Run:
    python scripts/spinning_shaft_report.py
"""

import math

import numpy as np

from varint import build_model
from varint.analysis.rod_modes import rod_modes
from varint.analysis.signals import nearest
from varint.scene.standard import SHAFT_SPIN_RATE as SPIN_RATE, shaft_scene, shaft_whirl

from _runs import blade_lattice_flap, blade_time_domain_flap, shaft_time_domain_whirl


def main():
    rows = []
    for n in (1, 2, 3):
        wf, wb = shaft_whirl(n)
        rows += [(f"mode {n} forward (ground {wf:.4f})", abs(wf - SPIN_RATE)), (f"mode {n} backward (ground {wb:.4f})", wb + SPIN_RATE)]
    pred = np.array([p for _, p in rows])
    errs = []
    for nodes in (21, 41, 81):
        f = [m["frequency"] for m in rod_modes(build_model(shaft_scene(nodes)), count=12)]
        errs.append(nearest(f, pred) / pred - 1)
    errs = np.array(errs)
    print("| whirl | theory, spinning frame (rad/s) | error at 20 / 40 / 80 elements | order |\n|---|---|---|---|")
    for i, (name, p) in enumerate(rows):
        e = errs[:, i]
        print(f"| {name} | {p:.4f} | {e[0]:+.2e} / {e[1]:+.2e} / {e[2]:+.2e} | {math.log2(abs(e[1] / e[2])):.2f} |")
    wf, wb = shaft_whirl(1)
    print("\n| time domain, 20 elements, 3 s | h | forward (theory 27.0187) | backward (theory 23.2145) |\n|---|---|---|---|")
    for h in (2e-3, 1e-3, 5e-4):
        w1, w2 = shaft_time_domain_whirl(h=h)
        print(f"| fitted whirl | {h:g} s | {w1:.4f} ({w1 / wf - 1:+.2e}) | {w2:.4f} ({w2 / wb - 1:+.2e}) |", flush=True)
    lattice = blade_lattice_flap()
    print(f"\nspun free rod (end over end, 40 elements): lattice flap mode {lattice:.4f} rad/s")
    for h in (2e-3, 1e-3):
        w = blade_time_domain_flap(h)
        print(f"  time domain, h = {h:g} s: {w:.4f} rad/s ({w / lattice - 1:+.2e})", flush=True)


if __name__ == "__main__":
    main()
