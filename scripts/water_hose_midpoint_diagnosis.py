"""Why the midpoint rule loses examples/water_filled_hose.toml: switch one effect off at a time and watch what grows.

The rubber hose full of water (quasistatic wall, incompressible water, 20 elements, 20 parcels, clamped-free, gravity,
h = 1 ms) fails Newton near t = 2.4 s under the midpoint rule (docs/validation.md, "Long runs").  Each variant below
edits the example's TOML text in one place and runs the midpoint rule to --end (or to its failure), recording every
10 steps the energy error on the motion's scale (abs(E - E0) over the largest kinetic energy plus the potential's
range over the first second), the frames' rotational kinetic energy (the shear-rotation band of docs/theory.md §12), the largest shear and
stretch, and the size of the step-to-step alternation (phase pi per step, the scheme's parasitic mode of §10.12) in
the rod's positions, its frames' angles, its strains, the labels, the radii and the water's pressures: the second difference x_{n+1} - 2x_n + x_{n-1}
of a mode flipping sign every step is 4 times its amplitude, that of the resolved motion h^2 times its acceleration.

Variants combine with "+" (no-water+h-0.5ms).  Most take 10-90 s of CPU to 4 s; the rigid wall ~270 s, the barotropic
liquid and the constrained rod in a dynamic wall several minutes (--budget stops a variant after that many CPU s).
The energy-momentum scheme (--scheme energy-momentum) runs the same records for comparison.

Run:  python scripts/water_hose_midpoint_diagnosis.py [--end 4] [--variants base,no-water,...] [--series base] [--budget 400]
Numbers: docs/theory.md §12f.
"""

from __future__ import annotations

import argparse
import re
import time
from pathlib import Path

import numpy as np

from varint import Simulation, build_model, parse_scene
from varint.errors import SolverError
from varint.terms.coupled import element_strains

ROOT = Path(__file__).resolve().parent.parent


def _drop(text, a, b):
    """The scene without the sections from header a up to header b."""
    i, j = text.index(a), text.index(b)
    return text[:i] + text[j:]


def _set(text, key, value):
    """Replace one 'key = value' line (the first)."""
    new, n = re.subn(rf"\n{key} = [^\n]*", f"\n{key} = {value}", text, count=1)
    assert n == 1, key
    return new


def _add(text, section, line):
    return text.replace(f"[{section}]\n", f"[{section}]\n{line}\n", 1)


#: one effect switched at a time (the TOML edits the docstring names)
VARIANTS = {
    "base": lambda t: t,
    "no-water": lambda t: _drop(t, "[wall]", "[environment]"),  # the empty rubber rod (tests/test_rod_constraint.py)
    "rigid-wall": lambda t: _drop(t, "[wall]", "[fluid]"),  # water in a wall of fixed radius: volumes held at the levels
    "dynamic-wall": lambda t: _set(t, "model", '"dynamic"'),  # wall with inertia: volumes held at the levels (§10.12)
    "parcels-40": lambda t: _set(t, "parcels", "40"),
    "parcels-10": lambda t: _set(t, "parcels", "10"),
    "h-2ms": lambda t: _set(t, "step", "2.0e-3"),
    "h-0.5ms": lambda t: _set(t, "step", "5.0e-4"),
    "h-0.25ms": lambda t: _set(t, "step", "2.5e-4"),
    "3d": lambda t: _set(t, "dimension", "3"),
    "inextensible": lambda t: _add(t, "rod", 'constraint = "inextensible_unshearable"'),
}


def _barotropic(t):
    """Water of finite compressibility (bulk modulus 2.2 GPa): no multipliers, so no constraint mode (§10.12)."""
    return t.replace('model = "incompressible"', 'model = "barotropic"\nbulk_modulus = 2.2e9')


VARIANTS["barotropic"] = _barotropic


def scene_text(variant, scheme="midpoint"):
    text = (ROOT / "examples" / "water_filled_hose.toml").read_text()
    text = text.replace('scheme = "energy-momentum"', f'scheme = "{scheme}"')
    for v in variant.split("+"):
        text = VARIANTS[v](text)
    return text


def _levels(sim):
    """The level's parts whose alternation is measured: node positions, frame angles, strains, labels, radii, pressures
    (from the fields, which every scheme writes alike)."""
    f = sim.fields()
    Lam, r = f["rod/Lambda"], f["rod/r"]
    ang = np.arctan2(Lam[:, 1, 0], Lam[:, 0, 0])  # the frame's turn about z (the planar motion's angle)
    Gamma = element_strains(Lam, r, sim.model.rod.ds)[0]  # body-frame strains: stretch Gamma_1 - 1, shear Gamma_2 (§9)
    out = {"r": r, "angle": np.unwrap(ang), "stretch": Gamma[:, 0] - 1.0, "shear": Gamma[:, 1]}
    for k, key in (("s", "fluid/s"), ("R", "wall/R"), ("p", "fluid/pressure")):
        if key in f:
            out[k] = f[key]
    return out


def _rot_kinetic(sim):
    """The frames' rotary kinetic energy at the level (the shear-rotation band, §12 D; §12c's directors' share)."""
    stp = sim.stepper
    if hasattr(stp, "D") and hasattr(stp, "V"):  # the energy-momentum step's directors and their velocities
        return 0.5 * float(np.sum(stp.E[:, None, :] * stp.V ** 2))
    m, st = sim.model, sim.state
    rod = m.rod
    n1 = rod.N + 1
    pp = st.p[m.rod_p]
    Pi = pp[3 * n1: 6 * n1].reshape(n1, 3) * rod.mask[:, 3:]
    return 0.5 * float(np.sum(Pi * Pi / np.where(rod.node_inertia > 0, rod.node_inertia, np.inf)))


def run(variant, end, every=10, scheme="midpoint", budget=float("inf")):
    text = scene_text(variant, scheme)
    text = re.sub(r"\nend = [0-9.e+-]+", f"\nend = {end}", text)
    sim = Simulation(build_model(parse_scene(text)), scheme=scheme)
    n = int(round(end / sim.h))
    rec = {k: [] for k in ("t", "E", "K", "Krot", "res", "shear", "stretch")}
    alt = {}
    hist = [_levels(sim)]
    why = "runs to the end"
    c0 = time.process_time()
    m0 = sim.monitors()
    E0 = m0["energy"]
    try:
        for i in range(n):
            if time.process_time() - c0 > budget:  # some variants (dynamic wall with the rod's constraint) are slow
                why = f"stopped at t = {sim.state.t:.3f} (CPU budget)"
                break
            sim.step()
            hist = (hist + [_levels(sim)])[-3:]
            if (i + 1) % every == 0 and len(hist) == 3:
                mo = sim.monitors()
                rec["t"].append(sim.state.t)
                rec["E"].append(mo["energy"])
                rec["K"].append(mo["kinetic_energy"])
                rec["Krot"].append(_rot_kinetic(sim))
                rec["res"].append(mo.get("constraint_residual", 0.0))
                rec["shear"].append(float(np.max(np.abs(hist[-1]["shear"]))))
                rec["stretch"].append(float(np.max(np.abs(hist[-1]["stretch"]))))
                for k in hist[-1]:
                    d2 = hist[2][k] - 2 * hist[1][k] + hist[0][k]
                    alt.setdefault(k, []).append(float(np.max(np.abs(d2))) if np.size(d2) else 0.0)
    except SolverError as exc:
        why = f"fails at t = {sim.state.t:.3f} ({str(exc)[:60]})"
    cpu = time.process_time() - c0
    rec = {k: np.array(v) for k, v in rec.items()}
    alt = {k: np.array(v) for k, v in alt.items()}
    U = rec["E"] - rec["K"]
    # the motion's scale from the swing before anything grows (the first second, or the first half of a shorter run):
    # over the whole run a failing variant's blow-up (K of tens of J) would shrink every earlier error
    early = rec["t"] <= min(1.0, 0.5 * sim.state.t) if len(U) else None
    scale = float(np.max(rec["K"][early]) + np.ptp(U[early])) if len(U) and np.any(early) else float("nan")
    err = np.abs(rec["E"] - E0) / scale
    return dict(variant=variant, h=sim.h, t_end=sim.state.t, why=why, scale=scale, err=err, rec=rec, alt=alt, cpu=cpu,
                halved=sim.stats.halved_steps)


def growth_rate(t, y, lo, hi):
    """Least-squares slope of log y on lo <= y <= hi (an exponential's rate, 1/s), with the window's times."""
    ok = (y > lo) & (y < hi)
    if np.count_nonzero(ok) < 5:
        return float("nan"), float("nan"), float("nan")
    return float(np.polyfit(t[ok], np.log(y[ok]), 1)[0]), float(t[ok][0]), float(t[ok][-1])


def at(t, y, times):
    return [float(y[np.searchsorted(t, x)]) if len(t) and x <= t[-1] else float("nan") for x in times]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--end", type=float, default=4.0)
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--series", default="", help="variants whose records to print at 0.25 s intervals")
    ap.add_argument("--scheme", default="midpoint")
    ap.add_argument("--budget", type=float, default=float("inf"), help="CPU seconds per variant")
    args = ap.parse_args()
    series = set(args.series.split(",")) if args.series else set()
    print("| variant | h [ms] | outcome | max abs(E - E0)/(max K + range U, t <= 1 s) | at t = 1 / 2 s | rate of the error [1/s] (window) | halved | CPU s |")
    print("|---|---|---|---|---|---|---|---|")
    for v in args.variants.split(","):
        r = run(v, args.end, scheme=args.scheme, budget=args.budget)
        t, err = r["rec"]["t"], r["err"]
        rate, a, b = growth_rate(t, err, 1e-6, 1e-1)
        e1, e2 = at(t, err, (1.0, 2.0))
        print(f"| {v} | {1e3 * r['h']:g} | {r['why']} | {np.max(err):.2e} | {e1:.1e} / {e2:.1e} | "
              f"{rate:.2f} ({a:.2f}-{b:.2f} s) | {r['halved']} | {r['cpu']:.0f} |", flush=True)
        if v in series:
            keys = list(r["alt"])
            print(f"  t | err | K | Krot/K | vol. residual | max shear | max stretch | " + " | ".join(f"d2 {k}" for k in keys))
            for x in np.arange(0.25, r["t_end"] + 1e-9, 0.25).tolist() + [t[-1]]:
                i = min(np.searchsorted(t, x - 1e-9), len(t) - 1)
                rc = r["rec"]
                print(f"  {t[i]:.3f} | {err[i]:.2e} | {rc['K'][i]:.3e} | {rc['Krot'][i] / rc['K'][i]:.2e} | "
                      f"{rc['res'][i]:.1e} | {rc['shear'][i]:.1e} | {rc['stretch'][i]:.1e} | " + " | ".join(f"{r['alt'][k][i]:.1e}" for k in keys), flush=True)


if __name__ == "__main__":
    main()
