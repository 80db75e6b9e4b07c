"""0.1's sloshing tube with [shock_capturing]: energy, and where the entropy is produced.

Scene (as tests/test_conservation.py and scripts/slosh_long_run.py): air in the closed rubber tube (R0 = 5 cm,
1 mm wall, E = 5 MPa, dynamic linear wall, p_ext = 1 atm), 1 m, 16 parcels on 17 nodes, a standing
pressure wave p = P0 (1 + A cos(pi s / L)) at rest.  At A = 20 % the conservative scheme's energy error
creeps (docs/validation.md): the wave steepens towards shocks.  With [shock_capturing]:

* total energy (gas and wall kinetic, internal, wall elastic, p_ext Vol) each step, relative to its start;
* the viscous heating W_k of each parcel per step (from its entropy change at the new volume: the heating's
  definition, varint.terms.shock_capturing), summed as the dissipated energy, relative to the largest kinetic
  energy of the run (the wave's energy scale);
* where it happens: the share of each step's heating carried by the two most heated parcels, averaged over
  the steps with weight W (2/16 = 0.125 for heating spread evenly over the 16 parcels);
* for A = 2, 5, 10, 20 %: how much of the wave's energy is dissipated, with the defaults (c_Q = 1,
  c_L = 0.5), with the quadratic term alone (c_L = 0), and with the defaults under Christensen's limiter
  (varint.terms.shock_capturing.limited), which switches Q off where the compression is smooth.

* a long 20 % run (default 10^5 steps of 40 us, 4 s, as docs/validation.md's energy table) without
  [shock_capturing], with the defaults and with the limiter: per twentieth of the run the steepest pressure
  jump between neighbouring parcels (relative to the initial cosine's), the heating, the energy error.

Run:  python scripts/slosh_shock_capture.py [--steps 2000] [--h 1e-5] [--parcels 16] [--long 100000]
      [--long-h 4e-5]      (about 15 min with the long runs, --long 0 skips them)
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from varint import Simulation, build_model
from varint.scene.standard import scene_of, sloshing_scene

P0 = 101325.0


def scene(amplitude, h=1e-5, parcels=16, shock=None):
    """The model of the sloshing scene (varint.scene.standard.sloshing_scene) at ``amplitude`` (fraction of P0);
    ``shock`` the [shock_capturing] keys or None."""
    extra = {} if shock is None else {"shock_capturing": shock}
    return build_model(scene_of(sloshing_scene(h, amplitude=amplitude, parcels=parcels, **extra)))


def _internal(t, V, S):
    g = t.eos.gamma
    return np.exp(S / t.eos.cv) * t.m ** g * V ** (1.0 - g) / (g - 1.0)


def run(amplitude, steps, h=1e-5, parcels=16, shock=None, every=100):
    """Run; returns a dict of series (t, energy error, kinetic energy, dissipated energy) and the localisation.

    ``shock``: the [shock_capturing] keys; ``limiter`` among them switches on Christensen's limiter
    (varint.terms.shock_capturing.limited) on the force after the model is built, whether or not the scene
    schema knows the key yet."""
    shock = dict(shock or {})
    limiter = shock.pop("limiter", False)
    model = scene(amplitude, h, parcels, shock)
    model.forces[0].limiter = limiter
    sim = Simulation(model)
    t = model.tube
    st = sim.state
    mon = sim.monitors()
    E0 = mon["energy"]
    # the wave's energy scale: the largest kinetic energy seen (gas and wall)
    Kmax = mon["kinetic_energy"]
    rows = []
    W_tot = 0.0
    share_num = share_den = 0.0
    err = 0.0
    entropy_ok = True
    wall0 = time.perf_counter()
    for n in range(steps):
        S_old = t.S.copy()
        sim.step()
        st = sim.state
        cfg = t.config(np.concatenate([st.q[model.tube_q], st.lam[model.tube_lam]]))
        V = t.volumes(cfg)
        W = _internal(t, V, t.S) - _internal(t, V, S_old)
        entropy_ok &= bool(np.all(t.S >= S_old))
        Wn = float(np.sum(W))
        W_tot += Wn
        if Wn > 0:
            top2 = np.sort(W)[-2:].sum()
            share_num += top2
            share_den += Wn
        mon = sim.monitors()
        Kmax = max(Kmax, mon["kinetic_energy"])
        err = max(err, abs(mon["energy"] / E0 - 1))
        if (n + 1) % every == 0:
            rows.append((st.t, mon["energy"] / E0 - 1, mon["kinetic_energy"], W_tot))
    return {"amplitude": amplitude, "rows": np.array(rows), "energy_error": err, "dissipated": W_tot, "Kmax": Kmax,
            "share_top2": share_num / share_den if share_den > 0 else float("nan"), "entropy_ok": entropy_ok,
            "wall": time.perf_counter() - wall0}


def long_run(steps, h, parcels, mode, windows=20, amplitude=0.2):
    """The long 20 % run: per window, the steepest pressure jump between neighbouring parcels over the window
    (relative to the initial cosine's, A P0 pi / M), the heating in the window relative to the largest
    kinetic energy, and the energy error.  ``mode``: "none" (no [shock_capturing]), "defaults", "limiter"."""
    model = scene(amplitude, h, parcels, None if mode == "none" else {})
    if mode != "none":
        model.forces[0].limiter = mode == "limiter"
    sim = Simulation(model)
    t = model.tube
    E0 = sim.monitors()["energy"]
    smooth = amplitude * P0 * np.pi / parcels
    per = steps // windows
    out = []
    steep = heat = err = Kmax = 0.0
    wall0 = time.perf_counter()
    for n in range(steps):
        S_old = t.S.copy() if mode != "none" else None
        sim.step()
        st = sim.state
        cfg = t.config(np.concatenate([st.q[model.tube_q], st.lam[model.tube_lam]]))
        rho, p, _ = t.fluid_fields(cfg, st.p[model.tube_p])
        steep = max(steep, float(np.max(np.abs(np.diff(p)))) / smooth)
        if S_old is not None:
            V = t.volumes(cfg)
            heat += float(np.sum(_internal(t, V, t.S) - _internal(t, V, S_old)))
        mon = sim.monitors()
        Kmax = max(Kmax, mon["kinetic_energy"])
        err = max(err, abs(mon["energy"] / E0 - 1))
        if (n + 1) % per == 0:
            out.append((st.t, steep, heat, err))
            steep = heat = 0.0
    rows = np.array(out)
    rows[:, 2] /= Kmax
    return rows, time.perf_counter() - wall0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--h", type=float, default=1e-5)
    ap.add_argument("--parcels", type=int, default=16)
    ap.add_argument("--long", type=int, default=100_000, help="steps of the long 20 %% run at --long-h (0: skip)")
    ap.add_argument("--long-h", type=float, default=4e-5)
    a = ap.parse_args(argv)
    print(f"{a.parcels} parcels, h = {a.h:g} s, {a.steps} steps ({a.steps * a.h:g} s)\n")
    print("| amplitude | Q | max abs(E/E0 - 1) | dissipated / max kinetic energy | share of heating in the top 2 parcels "
          "| entropy non-decreasing | wall [s] |")
    print("|---|---|---|---|---|---|---|")
    for A in (0.02, 0.05, 0.1, 0.2):
        for shock in ({}, {"linear": 0.0}, {"limiter": True}):
            r = run(A, a.steps, a.h, a.parcels, shock, every=max(1, a.steps // 10))
            cL = f"{shock.get('linear', 0.5):g}" + (", limiter" if shock.get("limiter") else "")
            print(f"| {A * 100:g} % | {cL} | {r['energy_error']:.1e} | {r['dissipated'] / r['Kmax']:.3f} | "
                  f"{r['share_top2']:.2f} | {r['entropy_ok']} | {r['wall']:.0f} |", flush=True)
    for shock in ({}, {"limiter": True}):
        r = run(0.2, a.steps, a.h, a.parcels, shock, every=max(1, a.steps // 10))
        print(f"\n20 %, {shock or 'defaults'}, over time: t, E/E0 - 1, kinetic energy, dissipated energy [J]")
        for row in r["rows"]:
            print("  %.3f  %+.1e  %.3e  %.3e" % tuple(row))
    if a.long:
        print(f"\nLong run: 20 %, {a.long} steps of {a.long_h:g} s; per twentieth of the run: steepest jump / initial "
              "cosine's, heating / max kinetic energy, max abs(E/E0 - 1) so far")
        for mode in ("none", "defaults", "limiter"):
            rows, wall = long_run(a.long, a.long_h, a.parcels, mode)
            print(f"\n{mode} ({wall:.0f} s)")
            for r in rows:
                print("  t %.2f  steep %.2f  heat %.3e  energy %.1e" % tuple(r))
            if mode != "none" and np.std(rows[:, 2]) > 0:
                print(f"  correlation of heating and steepness over the windows: {np.corrcoef(rows[:, 1], rows[:, 2])[0, 1]:+.2f}")


if __name__ == "__main__":
    main()
