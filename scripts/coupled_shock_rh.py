"""Rankine–Hugoniot across a shock captured in a bent, spinning, translating tube (issue 10; docs/validation.md,
"Shock capturing in the coupled tube"; docs/theory.md §11a "In the coupled tube").

Sod's data (1, 0, 1) | (0.125, 0, 0.1) in a free rod-borne tube of 1 m and 1 m^2 (p_ext = 0), bent (body
curvature (0, 1, 0.5) 1/m), spinning at 2 rad/s about z and translating at (0.3, -0.2, 0.1) m/s: the tube's points
move at up to ~1 m/s, near the gas's sound speed (1.18 m/s).  [shock_capturing] with its defaults.  The run is
written every step around t = 0.15 s and varint.analysis.shock_measure.measure_coupled_shock reads the states 4 parcels either side
of the captured shock (Gamma, gam from the rod's fields, u = ds/dt, rho, p) and evaluates the generalised
conditions RH_mass, RH_momentum, RH_energy.  Also printed: energy error (rod + gas + heat) against the viscous
work, momenta drift, entropy monotonicity.

    PYTHONPATH=. python scripts/coupled_shock_rh.py [M ...]      (default 100 200 400; ~1 min on one core)
"""

import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from varint import Simulation, build_model
from varint.analysis.shock_measure import measure_coupled_shock
from varint.run.io import RunWriter
from varint.scene.standard import BENT_SPINNING, SOD, SOD_GAMMA, coupled_sod, scene_of

T_MEASURE = 0.15
#: parcels either side of the steepest jump at which the two states are read (the first is the main one)
OFFSETS = (4, 6, 8, 12)
#: where the shock is looked for (reference s): the right-running shock of Sod's data
WINDOW = (0.55, 0.95)
#: the cases: a stiff (EA = 1e4 N, stretched 1e-4 by the gas) and a soft (EA = 5 N, stretched ~7 %) tube, bent and
#: spinning and translating or straight and free; the stiff straight tube held at both ends (the method's floor); and
#: the bent spinning tube with a dynamic wall (varint.scene.standard.SOD_WALL: swollen ~0.8 % by the gas)
CASES = {
    "bent spinning": dict(initial=BENT_SPINNING),
    "bent soft": dict(initial=BENT_SPINNING, axial_stiffness=5.0),
    "straight soft": dict(initial=None, axial_stiffness=5.0),
    "straight held": dict(initial=None, ends=("clamped", "clamped")),
    "bent dyn. wall": dict(initial=BENT_SPINNING, wall={"model": "dynamic"}),
}
#: time either side of T_MEASURE written every step (the speed's baseline: the shock crosses 0.06 m of s in 2 T_SPAN)
T_SPAN = 0.015
#: time either side of T_MEASURE over which each side's state is averaged
T_AVERAGE = 0.008


def run(M, tmp, initial=BENT_SPINNING, ends=("free", "free"), label="bent spinning", axial_stiffness=None, wall=None):
    cmax = math.sqrt(SOD_GAMMA * SOD[0][2] / SOD[0][0])
    n = int(math.ceil(T_MEASURE * M * cmax / 0.5))
    h = T_MEASURE / n
    SPAN = int(round(T_SPAN / h))
    d = coupled_sod(M=M, h=h, end=T_MEASURE + SPAN * h, initial=initial, ends=ends, wall=wall)
    if axial_stiffness is not None:
        d["rod"]["axial_stiffness"] = axial_stiffness
    scene = scene_of(d)
    model = build_model(scene)
    sim = Simulation(model)
    m0 = sim.monitors()
    E0, P0, J0 = m0["energy"], m0["linear_momentum"], m0["angular_momentum"]
    S = model.tube.S.copy()
    dE = dP = dJ = 0.0
    path = Path(tmp) / f"coupled_shock_{M}.h5"
    w = None
    t0 = time.time()
    for k in range(n + SPAN):
        sim.step()
        mo = sim.monitors()
        assert np.all(model.tube.S >= S), "entropy decreased"
        S = model.tube.S.copy()
        dE = max(dE, abs(mo["energy"] - E0))
        dP = max(dP, float(np.abs(mo["linear_momentum"] - P0).max()))
        dJ = max(dJ, float(np.abs(mo["angular_momentum"] - J0).max()))
        if k >= n - SPAN - 1:  # records every step, SPAN steps either side of T_MEASURE (step k ends at (k + 1) h)
            if w is None:
                w = RunWriter(str(path), scene, sim.h, mo, sim.fields())
            w.append(sim.state.t, mo, sim.fields(), sim.state)
    w.close()
    avg = int(round(T_AVERAGE / h))
    res = measure_coupled_shock(str(path), offset=OFFSETS[0], average=avg, window=WINDOW)
    more = {o: measure_coupled_shock(str(path), offset=o, average=avg, window=WINDOW)["relative"] for o in OFFSETS[1:]}
    work = model.tube.shock_capturing.total_work
    print(f"{label:14s} M = {M:4d}  h = {h:.3e}  steps {n + SPAN}  ({time.time() - t0:.0f} s)")
    print(f"   energy error {dE:.2e} (viscous work {work:.3e}, E0 {E0:.4f}); |dP| {dP:.1e}  |dJ| {dJ:.1e}")
    L, R = res["left"], res["right"]
    print(f"   shock at s = {res['position']:.4f}, speed c = {res['speed']:.4f} (in s; exact straight-tube Sod 1.7522)")
    print(f"   left  rho {L.rho:.4f} u {L.u:.4f} p {L.p:.4f} |Gamma| {np.linalg.norm(L.Gamma):.6f} gam {np.round(L.gam, 4)} Q {L.Q:.5f}")
    print(f"   right rho {R.rho:.4f} u {R.u:.4f} p {R.p:.4f} |Gamma| {np.linalg.norm(R.Gamma):.6f} gam {np.round(R.gam, 4)}")
    rel, cl = res["relative"], res["classical_relative"]
    print("   RH relative residuals (generalised): " + "  ".join(f"{k} {rel[k]:.2e}" for k in ("mass", "momentum", "energy")))
    print("   (straight-tube conditions, same data):  " + "  ".join(f"{k} {cl[k]:.2e}" for k in ("mass", "momentum", "energy")))
    for o, r in more.items():
        print(f"   offset {o}:  " + "  ".join(f"{k} {r[k]:.2e}" for k in ("mass", "momentum", "energy")))
    return res, dE, work


if __name__ == "__main__":
    Ms = [int(a) for a in sys.argv[1:]] or [100, 200, 400]
    with tempfile.TemporaryDirectory() as tmp:
        for label, kw in CASES.items():
            for M in Ms:
                run(M, tmp, label=label, **kw)
