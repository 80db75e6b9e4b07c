"""The paper's traveling shock in the rubber tube, carried by [shock_capturing] (docs/theory.md §11, §11a).

Scene: examples/rubber_tube_traveling_shock.toml (R0 = 5 cm, air at 1 atm ahead, p_ext = 1 atm, the paper's
beta1 = 1.14e5, beta2 = 8.37e5, a = 0.4782; 2 m tube, closed ends), with [shock_capturing] at its defaults.

Two starts:

* ``profile``: the traveling wave of speed c = 447 m/s (varint.exact.shocks.traveling_shock) with the shock at
  s = 1 m, as ``[initial.traveling_shock]`` sets it.  We track the captured shock (the steepest pressure
  jump between neighbouring parcels, refined to where the pressure crosses the mean of the wave's two
  states at the shock), fit its speed over the run, and compare the captured fields at fixed distances
  behind and ahead of the shock with the wave's profile there (and with the far state behind).
* ``step``: the far states only, joined by a step at s = 1 m: (rho+, u+, p+, R+) behind, the gas at rest
  at R0 ahead.  Does the step settle into the 447 m/s wave?  (Also ``rest``: the same but the gas behind
  at rest, a pressure step in a tube swollen to its static radius.)

The run stops before the left end's rarefaction (its head moves at u + c ~ 790 m/s from s = 0) reaches the
measurement points behind the shock and before the precursor ahead reaches the right end.

Run:  python scripts/traveling_shock_capture.py [--parcels 400,800] [--start profile,step,rest]
      [--end 1.2e-3] [--cfl 0.4] [--limiter]      (a few minutes for the defaults)
"""

from __future__ import annotations

import argparse
import math
import time
import tomllib
from pathlib import Path

import numpy as np

from varint import Simulation, build_model, parse_scene
from varint.exact.shocks import ideal_gas_state, relative_residuals, rh_residuals, traveling_shock
from varint.scene.derived import tube_of_scene
from varint.scene.text import to_toml

ROOT = Path(__file__).resolve().parent.parent
EXAMPLE = ROOT / "examples" / "rubber_tube_traveling_shock.toml"
SPEED = 447.0
X0 = 1.0
#: distances from the shock (m, negative: behind) where the captured fields are compared with the wave's profile
OFFSETS = (-0.3, -0.2, -0.1, -0.05, 0.1, 0.2)
#: parcels either side of the captured shock whose states enter the jump conditions (varint.analysis.shock_measure.measure_shock's default)
RH_OFFSET = 4


def scene_dict(parcels, start="profile", h=None, end=1.2e-3, shock=True):
    """The example's scene with ``parcels`` parcels (nodes = parcels + 1) and the chosen start."""
    d = tomllib.loads(EXAMPLE.read_text())
    d["tube"]["nodes"] = parcels + 1
    d["fluid"]["parcels"] = parcels
    if shock:
        d["shock_capturing"] = {}
    if h is not None:
        d["time"]["step"] = h
    d["time"]["end"] = end
    if start != "profile":
        wave = wave_of(d)
        d.pop("initial")
        behind = {"from": 0.0, "to": X0, "density": wave.rho_plus, "pressure": wave.p_plus}
        if start == "step":
            behind["velocity"] = wave.u_plus
        d["fluid"]["initial"] = [behind]
        d["wall"]["perturbation"] = [{"field": "R", "shape": "step", "amplitude": wave.R_plus - wave.R_minus,
                                      "from": 0.0, "to": X0}]
    return d


def wave_of(d):
    """The 447 m/s traveling shock of the scene's tube and gas."""
    sc = parse_scene(to_toml({k: v for k, v in d.items() if k != "initial"}))
    return traveling_shock(tube_of_scene(sc), SPEED)


def fields(sim):
    """Parcel centres, density, pressure, parcel velocity (mean of its labels) and the wall radius at the centres."""
    m, st = sim.model, sim.state
    t = m.tube
    cfg = t.config(np.concatenate([st.q[m.tube_q], st.lam[m.tube_lam]]))
    rho, p, u_lab = t.fluid_fields(cfg, st.p[m.tube_p])
    c = 0.5 * (cfg.s[:-1] + cfg.s[1:])
    return c, rho, p, 0.5 * (u_lab[:-1] + u_lab[1:]), t.radius_at(c, cfg)


def shock_position(c, p, level, search=None):
    """Where the pressure crosses ``level`` next to the steepest pressure jump between neighbouring parcels
    (within ``search = (a, b)`` when given): the shock's position, to a fraction of a parcel."""
    dp = np.abs(np.diff(p))
    if search is not None:
        dp = np.where((c[:-1] >= search[0]) & (c[1:] <= search[1]), dp, -1.0)
    i = int(np.argmax(dp))
    lo, hi = max(i - 4, 0), min(i + 5, len(p) - 1)
    for j in range(lo, hi):  # the crossing of the level nearest the steepest jump
        a, b = p[j], p[j + 1]
        if (a - level) * (b - level) <= 0 and a != b:
            return c[j] + (level - a) / (b - a) * (c[j + 1] - c[j])
    return 0.5 * (c[i] + c[i + 1])


def sample(c, f, x):
    return np.interp(x, c, f)


def run(parcels, start="profile", end=1.2e-3, cfl=0.4, every=None, progress=False, limiter=False):
    """Run one case; returns a dict with the track (t, x_shock), the fitted speed and the comparisons.

    ``limiter``: Christensen's limiter on the viscous pressure (varint.terms.shock_capturing.limited)."""
    ds = 2.0 / parcels
    h = cfl * ds / 800.0  # 800 m/s: the fastest characteristic behind the shock (u + c)
    n = int(math.ceil(end / h))
    h = end / n
    d = scene_dict(parcels, start, h=h, end=end)
    wave = wave_of(d)
    level = 0.5 * (wave.ahead[2] + wave.behind[2])  # the wave's pressures either side of the shock
    sim = Simulation(build_model(parse_scene(to_toml(d))))
    sim.model.forces[0].limiter = limiter
    t = sim.model.tube
    E0 = sim.monitors()["energy"]
    S_prev = t.S.copy()
    every = every or max(1, n // 60)
    track_t, track_x = [], []
    entropy_ok = True
    energy_err = 0.0
    t0 = time.perf_counter()
    for k in range(n + 1):
        if k % every == 0 or k == n:
            c, rho, p, u, R = fields(sim)
            # search near where the shock should be (the step start makes no wave at the right at t = 0)
            x_pred = X0 + SPEED * sim.state.t
            track_t.append(sim.state.t)
            track_x.append(shock_position(c, p, level, search=(x_pred - 0.3, x_pred + 0.3)))
            E = sim.monitors()["energy"]
            energy_err = max(energy_err, abs(E / E0 - 1))
            if progress:
                print(f"  t {sim.state.t:.3e}  x_shock {track_x[-1]:.4f}  energy {E / E0 - 1:+.1e}", flush=True)
        if k == n:
            break
        sim.step()
        entropy_ok &= bool(np.all(t.S >= S_prev))
        S_prev = t.S.copy()
    wall = time.perf_counter() - t0
    track_t, track_x = np.array(track_t), np.array(track_x)
    # the speed over the second half of the run (the step start needs time to form its wave)
    half = track_t >= 0.5 * end
    speed = float(np.polyfit(track_t[half], track_x[half], 1)[0])
    speed_all = float(np.polyfit(track_t, track_x, 1)[0])
    c, rho, p, u, R = fields(sim)
    xs = track_x[-1]
    off = np.array(OFFSETS)
    Rw, rhow, uw, pw = wave.profile(off)
    cmp_ = {}
    for name, got, want in (("p", sample(c, p, xs + off), pw), ("rho", sample(c, rho, xs + off), rhow),
                            ("u", sample(c, u, xs + off), uw), ("R", sample(c, R, xs + off), Rw)):
        cmp_[name] = (got, want)
    # the state just behind the captured front (mean over 3-10 cm behind it) and the lowest pressure ahead
    beh = (c > xs - 0.10) & (c < xs - 0.03)
    ahead = (c > xs) & (c < xs + 0.3)
    front = {"p": float(np.mean(p[beh])), "rho": float(np.mean(rho[beh])), "u": float(np.mean(u[beh])),
             "R": float(np.mean(R[beh])), "p_min_ahead": float(np.min(p[ahead]))}
    # the paper's jump conditions (RH_mass, RH_momentum, RH_energy; straight tube, Q = pi R^2) across the
    # captured shock: the states `offset` parcels either side of its steepest jump, the fitted speed; and the
    # same for the wave's profile sampled at those two positions (what the smooth variation over that span
    # alone leaves)
    g = wave.tube.gamma
    i = int(np.argmin(np.abs(0.5 * (c[:-1] + c[1:]) - xs)))
    il, ir = i - RH_OFFSET, i + 1 + RH_OFFSET
    left = ideal_gas_state(rho[il], u[il], p[il], g, R=R[il])
    right = ideal_gas_state(rho[ir], u[ir], p[ir], g, R=R[ir])
    Rw2, rw2, uw2, pw2 = wave.profile(np.array([c[il] - xs, c[ir] - xs]))
    wl = ideal_gas_state(rw2[0], uw2[0], pw2[0], g, R=Rw2[0])
    wr = ideal_gas_state(rw2[1], uw2[1], pw2[1], g, R=Rw2[1])
    rh = {"captured": relative_residuals(rh_residuals(left, right, speed)),
          "wave": relative_residuals(rh_residuals(wl, wr, SPEED)), "span": float(c[ir] - c[il]),
          # the two states themselves, captured and the wave's at the same places: (rho, u, p, R) behind, ahead
          "states": {"captured": ((rho[il], u[il], p[il], R[il]), (rho[ir], u[ir], p[ir], R[ir])),
                     "wave": ((rw2[0], uw2[0], pw2[0], Rw2[0]), (rw2[1], uw2[1], pw2[1], Rw2[1]))}}
    return {"parcels": parcels, "start": start, "limiter": limiter, "front": front, "rh": rh, "h": h, "steps": n, "wall": wall, "t": track_t, "x": track_x,
            "speed": speed, "speed_all": speed_all, "travel": float(track_x[-1] - track_x[0]),
            "compare": cmp_, "energy_error": energy_err, "entropy_ok": entropy_ok, "wave": wave,
            "newton": sim.stats.total_iterations / n}


def report(r):
    w = r["wave"]
    print(f"\n### start = {r['start']}{', limiter' if r['limiter'] else ''}, {r['parcels']} parcels (ds = {2.0 / r['parcels'] * 1e3:.1f} mm), "
          f"h = {r['h']:.2e} s, {r['steps']} steps, {r['wall']:.0f} s")
    print(f"shock travel {r['travel']:.3f} m = {r['travel'] / 0.05:.1f} R0; speed (second half) {r['speed']:.2f} m/s "
          f"({(r['speed'] / SPEED - 1) * 100:+.2f} % of {SPEED:g}), whole run {r['speed_all']:.2f} m/s; "
          f"max |E/E0 - 1| {r['energy_error']:.1e}; entropy non-decreasing: {r['entropy_ok']}; "
          f"Newton iterations/step {r['newton']:.1f}")
    print("\nCaptured minus wave profile at fixed distances from the captured shock, relative to the far state behind:\n")
    print("| x - x_shock [m] | " + " | ".join(f"{o:+.2f}" for o in OFFSETS) + " |")
    print("|---|" + "---|" * len(OFFSETS))
    far = {"p": w.p_plus, "rho": w.rho_plus, "u": w.u_plus, "R": w.R_plus}
    for name, (got, want) in r["compare"].items():
        print(f"| {name} | " + " | ".join(f"{(g - v) / far[name] * 100:+.2f} %" for g, v in zip(got, want)) + " |")
    rh = r["rh"]
    print(f"jump conditions across the captured shock (states {RH_OFFSET} parcels either side, {rh['span'] * 100:.1f} cm "
          "apart), relative residuals mass / momentum / energy: "
          + " / ".join(f"{rh['captured'][k]:.1e}" for k in ("mass", "momentum", "energy"))
          + "; the wave's own profile at the same two points: "
          + " / ".join(f"{rh['wave'][k]:.1e}" for k in ("mass", "momentum", "energy")))
    f = r["front"]
    print(f"captured front: 3-10 cm behind it p {f['p']:.0f} Pa, rho {f['rho']:.4f}, u {f['u']:.1f} m/s, R {f['R'] * 1e3:.2f} mm; "
          f"lowest pressure within 30 cm ahead {f['p_min_ahead']:.0f} Pa (wave: {w.ahead[2]:.0f} Pa just ahead of the shock)")
    print(f"far state behind (wave): p+ {w.p_plus:.0f} Pa, rho+ {w.rho_plus:.4f}, u+ {w.u_plus:.2f} m/s, "
          f"R+ {w.R_plus * 1e3:.2f} mm; at the shock R {w.R_shock * 1e3:.2f} mm")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--parcels", default="400,800")
    ap.add_argument("--start", default="profile,step,rest")
    ap.add_argument("--end", type=float, default=1.2e-3)
    ap.add_argument("--cfl", type=float, default=0.4)
    ap.add_argument("--progress", action="store_true")
    ap.add_argument("--limiter", action="store_true", help="Christensen's limiter on the viscous pressure")
    a = ap.parse_args(argv)
    for start in a.start.split(","):
        for N in (int(x) for x in a.parcels.split(",")):
            report(run(N, start, end=a.end, cfl=a.cfl, progress=a.progress, limiter=a.limiter))


if __name__ == "__main__":
    main()
