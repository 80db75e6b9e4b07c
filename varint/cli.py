"""Command line: ``varint run | check | info | plot | export | static | modes | sweep | shock``.

Every failure the user can cause (bad scene, unreadable file, an output that would
replace a file, Newton failure) prints one line per problem prefixed ``varint: error:``
and exits 2.  Ctrl-C prints one line and exits 130 (for ``run``: the file and how to
resume it); a reader that closes the pipe early ends the command quietly (exit 141).
Nothing else is caught, so a traceback always means a bug in varint.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import shlex
import sys

import numpy as np

from .version import __version__
from .errors import VarintError

__all__ = ["main"]


def _jsonable(x):
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, np.generic):
        return x.item()
    return x


class _Interrupted(Exception):
    """Ctrl-C, with what the user should know about the file it left (one line)."""


def _load_scene(path):
    from .scene.schema import load_scene

    return load_scene(path)


def _resumable_records(path, scene):
    """Complete records of ``scene``'s run in ``path`` (0 if it is not one, or cannot be read)."""
    import h5py

    try:
        with h5py.File(path, "r", locking=False) as f:
            if f.attrs.get("static", False) or f.attrs.get("scene_toml") != scene.text:
                return 0
            return int(f.attrs.get("records", 0))
    except (OSError, ValueError, TypeError):
        return 0


def cmd_run(args):
    from .run.runner import check_output, default_output, run_scene

    scene = _load_scene(args.scene)
    out = args.output or default_output(scene, args.scene)
    check_output(out, args.scene, resume=args.resume, force=args.force)
    if args.resume:
        from .run.io import check_resumable

        check_resumable(out, scene)  # a static file, another scene's run, a failed run: one line, before any work
    if scene.end_note:
        print(f"varint: note: {scene.end_note}", file=sys.stderr)
    try:
        sim = run_scene(scene, out, resume=args.resume, progress=None if not args.quiet else False)
    except KeyboardInterrupt:
        k = _resumable_records(out, scene)
        if k:
            raise _Interrupted(f"interrupted; {out} holds {k} complete record{'s' if k > 1 else ''} (continue with: "
                               f"varint run {shlex.quote(str(args.scene))} -o {shlex.quote(str(out))} --resume)") from None
        raise
    st = sim.state
    print(f"wrote {out}: {st.n} steps to t = {st.t:.6g} s ({sim.stats.total_iterations} Newton iterations, "
          f"{sim.stats.total_jacobians} Jacobians)")
    return 0


def _ends_text(scene):
    """The fluid's ends in words: closed, periodic, or the open pair with the inlet's and the outlet's data."""
    f = scene.fluid
    if f is None or f.ends.s0 == "closed":
        return "closed ends"
    if f.ends.s0 == "periodic":
        return "periodic ends"
    e = f.ends
    inlet = (f"velocity inlet at {e.inflow_velocity:g} m/s" if e.inflow == "velocity"
             else f"pressure inlet at {e.inflow_pressure:g} Pa")
    return f"open ends ({inlet}; outlet at {e.outflow_pressure:g} Pa)"


def cmd_check(args):
    from .model.model import build_model

    from .schemes.registry import check_supported, refusals

    scene = _load_scene(args.scene)
    model = build_model(scene)
    scheme = check_supported(model)  # the scene's scheme must step its model: one line with the reason otherwise
    d = {"title": scene.title, **model.describe(),
         "time": dict(scene.time, steps=scene.steps, **({"note": scene.end_note} if scene.end_note else {})),
         "environment": {k: v for k, v in scene.environment.items()}}
    own = scheme.unknowns(model)
    if own is not None:  # a scheme that solves for its own unknowns (energy-momentum: docs/theory.md §12a-§12b)
        d["unknowns"], d["inertial_unknowns"], d["algebraic_unknowns"] = own
        d["unknowns_total"] = d["inertial_unknowns"] + d["algebraic_unknowns"]
    d["schemes"] = {name: "runs" if why is None else why for name, why in refusals(model).items()}
    if args.json:
        print(json.dumps(_jsonable(d), indent=2))
        return 0
    print(f"scene: {args.scene}\n  title: {scene.title}")
    print(f"  effects: {', '.join(d['effects'])}")
    print(f"  terms of the discrete Lagrangian: {', '.join(d['terms'])}")
    if d.get("forces"):
        print(f"  non-conservative forces (Lagrange-d'Alembert): {', '.join(d['forces'])}")
    print("  unknowns: " + ", ".join(f"{k} ({v})" for k, v in d["unknowns"].items())
          + f"; total {d['unknowns_total']} ({d['inertial_unknowns']} inertial, {d['algebraic_unknowns']} algebraic)")
    print(f"  expected invariants: {', '.join(d['invariants']) or 'none (every symmetry is broken by a force, a load or a support)'}")
    lat = d["lattice"]
    if "rod" in d and scene.fluid is not None:
        per = lat["parcels"] / max(lat["elements"], 1)
        hint = ""
        if scene.fluid.ends.s0 not in ("closed", "periodic") and per < 2:
            hint = (" — fewer than 2 parcels per element: at fast flows the labels passing the nodes pump lattice "
                    "modes (docs/theory.md §12)")
        print(f"  lattice: {lat['elements']} elements, ds = {lat['ds']:.6g} m, {lat['parcels']} parcels "
              f"({per:.3g} per element), {_ends_text(scene)}{hint}")
    elif "rod" in d:
        print(f"  lattice: {lat['elements']} elements, ds = {lat['ds']:.6g} m")
    if "rod" in d:
        print("  rod: " + ", ".join(f"{k} = {v:.6g}" if isinstance(v, float) else f"{k} = {v}" for k, v in d["rod"].items()))
        print(f"  initial shape: {d['initial_shape']}")
    else:
        print(f"  lattice: {lat['elements']} elements, ds = {lat['ds']:.6g} m, {lat['parcels']} parcels, {_ends_text(scene)}")
    if "wall" in d:
        print("  wall: " + ", ".join(f"{k} = {v:.6g}" if isinstance(v, float) else f"{k} = {v}" for k, v in d["wall"].items()))
    if "fluid" in d:
        print("  fluid: " + ", ".join(f"{k} = {v:.6g}" if isinstance(v, float) else f"{k} = {v}" for k, v in d["fluid"].items()))
    t = scene.time
    chosen = "" if t.scheme == model.scheme else f" (stepped by {model.scheme})"
    print(f"  time: scheme = {t.scheme}{chosen}, step = {t.step:g} s, end = {t.end:g} s ({scene.steps} steps), newton_tol = {t.newton_tol:g}")
    if scene.end_note:
        print(f"  note: {scene.end_note}")
    print("  schemes: " + "; ".join(f"{name}: {what}" for name, what in d["schemes"].items()))
    return 0


def cmd_info(args):
    from .run.io import summary

    d = summary(args.file)
    if args.json:
        print(json.dumps(_jsonable(d), indent=2))
    else:
        for k, v in d.items():
            print(f"{k}: {v}")
    return 0


def _times(text):
    """``--at T1,T2,...``: the times [s], or a one-line error."""
    try:
        times = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        times = []
    if not times or not all(np.isfinite(times)):
        raise VarintError(f"--at {text!r}: give times in seconds separated by commas, e.g. --at 0,0.1,0.2")
    return times


def cmd_plot(args):
    from .plotting import plot_run
    from .run.runner import check_output_dir

    # where the pictures go is checked before anything is read or drawn (default: beside the file)
    check_output_dir(args.outdir if args.outdir else os.path.dirname(os.path.abspath(args.file)))

    times = _times(args.at) if args.at is not None else None
    for p in plot_run(args.file, args.outdir):
        print(f"wrote {p}")
    if times is not None:
        from .plotting import plot_profiles

        p, drawn = plot_profiles(args.file, times, args.outdir)
        if p is None:
            print("varint: note: --at draws a tube's p, rho, u, R; this run has no fluid or wall fields", file=sys.stderr)
        else:
            pairs = ", ".join(f"{d:.6g} s" + ("" if d == T else f" (nearest to {T:g})") for T, d in zip(times, drawn))
            print(f"wrote {p}: profiles at t = {pairs}")
    if args.animate:
        from .plotting import animate_run

        p = animate_run(args.file, args.outdir)
        if p is None:
            print("varint: note: --animate draws a rod's centreline; this run has no rod", file=sys.stderr)
        else:
            print(f"wrote {p}")
    return 0


def cmd_export(args):
    """``varint export OUT.h5 --xdmf``: an XDMF sidecar for ParaView and VisIt (varint.run.xdmf)."""
    from .run.xdmf import write_xdmf

    if not args.xdmf:
        raise VarintError("export: choose a format (--xdmf)")
    p = write_xdmf(args.file, args.output, force=args.force)
    print(f"wrote {p}: the rod, fluid and wall fields of {args.file} over time, read in place (open it in ParaView or VisIt)")
    return 0


def cmd_modes(args):
    from .analysis.modes import scene_modes

    d = scene_modes(_load_scene(args.scene), count=args.count, about=args.about, source=args.scene)
    if "remark" in d:
        print(f"# {d['remark']}", file=sys.stderr)
    if "note" in d:
        print(f"varint: note: {d['note']}", file=sys.stderr)
    res, frame = d["modes"], d.get("frame")
    if args.json:
        print(json.dumps(_jsonable({k: d[k] for k in ("modes", "about", "note", "frame", "flow") if k in d})))
    else:
        if "flow" in d:
            fl = d["flow"]
            print(f"# tube conveying fluid at U = {fl['U']:.6g} m/s: u = {fl['u']:.6g}, beta = {fl['beta']:.6g}, "
                  f"gamma = {fl['gamma']:.6g} (Païdoussis); growth rate < 0: the mode decays")
        if frame is not None:
            print(f"# {frame['note']}, angular velocity {frame['angular_velocity']} rad/s")
        for i, m in enumerate(res):
            whirl = (f"  {m['whirl']} whirl, {m['lab_frequency']:.8g} rad/s in the lab" if m.get("whirl") else "")
            print(f"{i:4d}  frequency {m['frequency']:.8g} rad/s  ({m['frequency'] / (2 * np.pi):.6g} Hz)  growth rate {m['growth_rate']:.3g} 1/s{whirl}")
    return 0


def cmd_static(args):
    import numpy as np

    from .model.model import build_model
    from .model.statics import static_equilibrium
    from .run.runner import check_output, default_output
    from .run.simulation import Simulation

    scene = _load_scene(args.scene)
    out = args.output or default_output(scene, args.scene, kind="static")
    check_output(out, args.scene, force=args.force, resumable=False)
    model = build_model(scene)
    if model.rod is None:
        return _static_tube(args, scene, model, out)
    if model.coupled and model.tube.open_ends:
        return _static_flowing(scene, model, out)
    if model.coupled:
        return _static_coupled(args, scene, model, out)
    spinning = bool(np.any(model.rod.spin))
    Lam, r, info = static_equilibrium(model, spin=model.rod.spin if spinning else None)
    # the steady rotation: its shape with the momenta of the rigid rotation; a static equilibrium: at rest
    model.rod.set_configuration(Lam, r, rest=not spinning)
    extra = {"steady_rotation": model.rod.spin, "turned_deg": info["turned_deg"]} if spinning else {}
    _write_static(out, scene, Simulation(model), info["load_steps"], extra)
    tip = r[-1]
    what = "steady rotation (shape at rest in the spinning frame)" if spinning else "static equilibrium"
    from .analysis.modes import turned_note

    if turned_note(info):
        what += f", with {turned_note(info)}"
    print(f"wrote {out}: {what} in {info['iterations']} Newton iterations over {info['load_steps']} load steps; "
          f"tip at ({tip[0]:.6g}, {tip[1]:.6g}, {tip[2]:.6g}) m")
    return 0


def _write_static(out, scene, sim, load_steps, extra=None):
    """A static file: the run-file layout with one record (the simulation's state) and the static attributes."""
    from .run.io import RunWriter

    w = RunWriter(out, scene, sim.h, sim.monitors(), sim.fields(), records=1)
    try:
        w.append(0.0, sim.monitors(), sim.fields(), sim.state)
        w.f.attrs["static"] = True
        w.f.attrs["load_steps"] = load_steps
        for k, v in (extra or {}).items():
            w.f.attrs[k] = v
        w.set_status("finished")
    finally:
        w.close()


def _static_tube(args, scene, model, out):
    """``varint static`` of the straight tube (varint.model.statics.tube_static, docs/theory.md §13.10): one record at
    rest; what has no isolated equilibrium (open ends, no [wall]) is refused in one line."""
    import numpy as np

    from .errors import VarintError as _VE
    from .model.statics import tube_static
    from .run.simulation import Simulation
    from .schemes.state import State

    try:
        z, info = tube_static(model)
    except _VE as exc:
        raise _VE(f"{args.scene}: {exc}") from None
    t = model.tube
    sim = Simulation(model)
    st = sim.state
    sim.state = State(0, 0.0, z[:t.nq], np.zeros_like(st.p), z[t.nq:], np.zeros_like(st.v), data=st.data)
    _write_static(out, scene, sim, 0)
    R = t.config(z).R
    print(f"wrote {out}: static equilibrium of the tube in {info['iterations']} Newton iterations; "
          f"radius {R.min():.6g} to {R.max():.6g} m")
    return 0


def _static_coupled(args, scene, model, out):
    """``varint static`` of the coupled tube (varint.analysis.coupled_modes.coupled_static): one record, at rest."""
    import numpy as np

    from .analysis.coupled_modes import coupled_static
    from .terms.rod import pack_level
    from .run.simulation import Simulation
    from .schemes.state import State

    (Lam, r, zt), info = coupled_static(model)
    t = model.tube
    sim = Simulation(model)
    st = sim.state
    q = np.concatenate([zt[:t.nq], pack_level(Lam, r)])
    lam = np.concatenate([zt[t.nq:], np.zeros(model.rod.nlam)])
    sim.state = State(0, 0.0, q, np.zeros_like(st.p), lam, np.zeros_like(st.v), data=st.data)
    _write_static(out, scene, sim, info.get("load_steps", 0))
    tip = r[-1]
    print(f"wrote {out}: static equilibrium of the coupled tube in {info.get('iterations', '?')} Newton iterations; "
          f"tip at ({tip[0]:.6g}, {tip[1]:.6g}, {tip[2]:.6g}) m")
    return 0


def _static_flowing(scene, model, out):
    """``varint static`` of a tube conveying fluid (open ``fluid.ends``): its steady flowing state under gravity
    (varint.analysis.flowing_modes.flowing_static, docs/theory.md §13.6) as one record: the rod at rest in the steady
    shape, the liquid flowing through it at the inlet's speed, its gauge pressures those of the steady plug flow,
    mu = p - p_ext = rho g.(X(s) - X(L)) at each parcel's centre (the free jet at p_ext), and the inextensible rod's
    multipliers the wall's tension: flowing_static's element forces are the effective axial force T - pA (it has no
    pressure unknown), while in the time-stepped tube the pressures act on the rod through the parcels' stretched
    volumes, so its multipliers n are T = (T - pA) + mu A along the element's axis (docs/theory.md §13.6).  What
    flowing_static cannot treat (a gas, a [wall], ...) is refused in one line naming the key."""
    from .analysis.flowing_modes import flowing_static, pipe_parameters
    from .run.simulation import Simulation

    (Lam, r), info = flowing_static(model)
    rod, t = model.rod, model.tube
    rod.set_configuration(Lam, r, rest=True)
    # the parcels hold their volumes on the steady centreline, as in a scene that starts in that shape (varint.model.model)
    t.coupled_rebase(model.open_volumes(np.r_[t.piston, t.q_init], Lam, r))
    sim = Simulation(model)  # the initial state: the liquid flowing at U along the steady centreline, the rod at rest
    st = sim.state
    lam = st.lam.copy()
    cfg = t.config(np.concatenate([st.q[model.tube_q], lam[model.tube_lam]]))
    g = np.asarray(rod.g, dtype=float)
    X = model.centreline(0.5 * (cfg.s[:-1] + cfg.s[1:]), r)[3]
    lam[model.tube_lam] = (t.m / t.V0) * ((X - r[-1]) @ g)
    par = pipe_parameters(model)
    if rod.constrained:
        n = info["element_forces"].copy()
        Xe = model.centreline((np.arange(rod.N) + 0.5) * rod.ds, r)[3]
        n[:, 0] += par["M"] * ((Xe - r[-1]) @ g)  # + mu A: the wall's tension T
        lam[model.rod_lam] = n[:, :rod.ncomp].ravel()
    st.lam = lam
    U = par["U"]
    _write_static(out, scene, sim, info["load_steps"], {"flow_velocity": U})
    tip = r[-1]
    print(f"wrote {out}: steady flowing state (U = {U:.6g} m/s) in {info['iterations']} Newton iterations over "
          f"{info['load_steps']} load steps; tip at ({tip[0]:.6g}, {tip[1]:.6g}, {tip[2]:.6g}) m")
    return 0


def cmd_shock(args):
    """``varint shock SCENE --speed C | --strength Z``: the traveling shock of the scene's tube (docs/theory.md §11)."""
    from .scene.derived import tube_of_scene
    from .exact.shocks import traveling_shock, traveling_shock_of_strength

    scene = _load_scene(args.scene)
    tube = tube_of_scene(scene)
    if args.speed is not None:
        ts = traveling_shock(tube, args.speed)
    else:
        ts = traveling_shock_of_strength(tube, args.strength)
    d = ts.as_dict()
    if args.json:
        print(json.dumps(_jsonable(d)))
        return 0
    atm = 101325.0
    print(f"traveling shock in {args.scene}: speed {d['speed']:.6g} m/s (Mach {d['mach']:.6g} into the gas ahead), "
          f"strength z = {d['strength']:.6g}")
    print(f"  ahead (at rest):  p = {d['p_minus']:.6g} Pa ({d['p_minus'] / atm:.4g} atm), R = {d['R_minus']:.6g} m, "
          f"rho = {d['rho_minus']:.6g} kg/m^3")
    print(f"  far behind:       p = {d['p_plus']:.6g} Pa ({d['p_plus'] / atm:.4g} atm), R = {d['R_plus']:.6g} m, "
          f"u = {d['u_plus']:.6g} m/s, rho = {d['rho_plus']:.6g} kg/m^3")
    print(f"  at the shock:     R = {d['R_shock']:.6g} m, p jumps {d['p_shock_ahead']:.6g} -> {d['p_shock_behind']:.6g} Pa")
    lo, hi = d["speed_range"]
    print(f"  admissible speeds: {lo:.6g} < c < {hi:.6g} m/s")
    return 0


def cmd_sweep(args):
    """``varint sweep SCENE --vary KEY=... --analysis run|modes --out DIR``: docs/output.md, "Sweeps"."""
    from .run.runner import check_output_dir
    from .sweep import finished_points, sweep

    check_output_dir(args.out)  # before the scene is read or a cluster started
    try:
        r = sweep(args.scene, args.vary, args.analysis, args.out, scheduler=args.scheduler, workers=args.workers,
                  count=args.count, about=args.about)
    except KeyboardInterrupt:
        k = finished_points(args.out)
        if k:
            raise _Interrupted(f"interrupted; {os.path.join(args.out, 'sweep.csv')} holds {k} finished point{'s' if k > 1 else ''} "
                               "(the same command continues the sweep: finished points are skipped)") from None
        raise
    parts = [f"{r['ok']} ok", f"{r['failed']} failed"] + ([f"{r['crashed']} crashed (retried by a re-run)"] if r["crashed"] else [])
    print(f"wrote {r['table']}: {r['points']} points ({r['computed']} computed, {r['skipped']} already done): "
          + ", ".join(parts))
    return 1 if r["crashed"] else 0


def build_parser():
    p = argparse.ArgumentParser(prog="varint", description="Variational integrator for expandable tubes conveying fluid.")
    p.add_argument("--version", action="version", version=f"varint {__version__}")
    sub = p.add_subparsers(dest="command", required=True)
    r = sub.add_parser("run", help="run a scene, writing an HDF5 run file")
    r.add_argument("scene")
    r.add_argument("-o", "--output", help="run file (default: [output].file or SCENE.h5)")
    r.add_argument("--resume", action="store_true", help="continue an interrupted run file")
    r.add_argument("--force", action="store_true", help="replace an existing run file")
    r.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    r.set_defaults(func=cmd_run)
    c = sub.add_parser("check", help="validate a scene; print effects, unknowns and invariants")
    c.add_argument("scene")
    c.add_argument("--json", action="store_true")
    c.set_defaults(func=cmd_check)
    i = sub.add_parser("info", help="summarise a run file")
    i.add_argument("file")
    i.add_argument("--json", action="store_true")
    i.set_defaults(func=cmd_info)
    pl = sub.add_parser("plot", help="PNG figures of a run file's monitors and fields")
    pl.add_argument("file")
    pl.add_argument("-d", "--outdir", default=None, help="folder for the PNGs (default: beside the file)")
    pl.add_argument("--animate", action="store_true",
                    help="also write FILE_anim.gif: the rod's centreline in 3D over time (the fluid's labels by pressure)")
    pl.add_argument("--at", metavar="T1,T2,...",
                    help="also write FILE_profiles.png: p, rho, u, R along the tube at the records nearest to these times [s], "
                         "with the exact solution where the scene has one (a Riemann problem, the traveling shock)")
    pl.set_defaults(func=cmd_plot)
    ex = sub.add_parser("export", help="an XDMF sidecar of a run file (FILE.xmf) for ParaView and VisIt, reading the "
                                       "HDF5 datasets in place")
    ex.add_argument("file")
    ex.add_argument("--xdmf", action="store_true", help="write the XDMF sidecar (the only format)")
    ex.add_argument("-o", "--output", help="sidecar path (default: FILE with the suffix .xmf)")
    ex.add_argument("--force", action="store_true", help="replace an existing sidecar")
    ex.set_defaults(func=cmd_export)
    s = sub.add_parser("static", help="static equilibrium of a [rod] scene (a spinning rod: its steady rotation; a tube "
                                      "conveying fluid: its steady flowing state), written as one frame")
    s.add_argument("scene")
    s.add_argument("-o", "--output", help="run file (default: SCENE_static.h5)")
    s.add_argument("--force", action="store_true", help="replace an existing file")
    s.set_defaults(func=cmd_static)
    m = sub.add_parser("modes", help="eigenfrequencies of the model linearised about the initial state")
    m.add_argument("scene")
    m.add_argument("--json", action="store_true")
    m.add_argument("-n", "--count", type=int, default=20, help="number of lowest modes (>= 1)")
    m.add_argument("--about", choices=("initial", "static"), default="initial",
                   help="linearise about the scene's initial state (default) or its loaded static equilibrium / steady rotation (rods)")
    m.set_defaults(func=cmd_modes)
    sw = sub.add_parser("sweep", help="run or linearise a scene over a product of key values, on a Dask cluster; DIR/sweep.csv")
    sw.add_argument("scene")
    sw.add_argument("--vary", action="append", default=[], metavar="KEY=START:STOP:NUM|KEY=V1,V2,...",
                    help="a dotted scene key (rod.initial.angular_velocity[0], fluid.perturbation[0].amplitude) and "
                         "its values: NUM from START to STOP inclusive, or a comma list; repeat for a product")
    sw.add_argument("--analysis", choices=("run", "modes"), required=True,
                    help="run: each point integrated into DIR/point_NNNN.h5; modes: as varint modes")
    sw.add_argument("--out", required=True, metavar="DIR", help="folder of sweep.csv (and the run files); a re-run skips its finished points")
    sw.add_argument("--scheduler", metavar="ADDRESS", help="an existing Dask scheduler (default: a local cluster)")
    sw.add_argument("--workers", type=int, metavar="N", help="local cluster: worker processes (default: one per core)")
    sw.add_argument("-n", "--count", type=int, default=20, help="modes: number of lowest modes per point (>= 1)")
    sw.add_argument("--about", choices=("initial", "static"), default="initial", help="modes: as for varint modes")
    sw.set_defaults(func=cmd_sweep)
    sh = sub.add_parser("shock", help="the traveling shock of a tube scene (linear wall, ideal gas at rest ahead)")
    sh.add_argument("scene")
    g = sh.add_mutually_exclusive_group(required=True)
    g.add_argument("--speed", type=float, help="shock speed c [m/s]")
    g.add_argument("--strength", type=float, help="shock strength z = (p_plus - p_minus)/p_minus")
    sh.add_argument("--json", action="store_true")
    sh.set_defaults(func=cmd_shock)
    return p


def main(argv=None):
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="varint: %(message)s")
    try:
        # Newton iterates may leave the physical domain (negative density, a frame at the Cayley
        # singularity): the solvers test every residual for finiteness and fail with one line, so
        # numpy's floating-point warnings would only add noise to that line
        with np.errstate(all="ignore"):
            code = args.func(args)
        sys.stdout.flush()  # a closed pipe shows here, not in the interpreter's last flush
        return code
    except VarintError as exc:
        for line in str(exc).splitlines():
            print(f"varint: error: {line}", file=sys.stderr)
        return 2
    except _Interrupted as exc:
        print(f"varint: {exc}", file=sys.stderr)
        return 130
    except KeyboardInterrupt:
        print("varint: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # the reader went away (``varint info F | head -1``): stop quietly, as a tool killed by SIGPIPE
        # would; what is left in stdout's buffer goes to /dev/null, not to a second error at exit
        try:
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())
        except (OSError, ValueError, AttributeError):
            pass
        return 141


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
