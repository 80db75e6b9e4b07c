"""Helpers the tests share (the standard scenes themselves are varint.scene.standard's)."""

import shutil
import stat
import subprocess

import numpy as np

from varint import Simulation, build_model, parse_scene
from varint.analysis.signals import zero_crossing_frequency
from varint.lattice.lie import cay
from varint.scene.standard import liquid_cantilever_scenes
from varint.scene.text import to_toml


#: a dynamic linear rubber wall (2 mm, 2 MPa) as a scene's [wall] section, for the straight tubes of the open-end and
#: modes tests
RUBBER_WALL_SECTION = """
[wall]
model = "dynamic"
law = "linear"
thickness = 0.002
density = 1100.0
youngs_modulus = 2.0e6
poisson_ratio = 0.45
"""


def run_record(t, monitors, fields, **attrs):
    """A run as varint.run.io.read_run returns it, made in memory (the plotting tests draw these)."""
    return {"time": np.asarray(t, dtype=float), "monitors": monitors, "fields": fields,
            "attrs": dict({"title": "test"}, **attrs)}


def rotations_about_x(a):
    """(K,) angles -> (K, 3, 3) rotations about x."""
    c, s = np.cos(a), np.sin(a)
    R = np.zeros(np.shape(a) + (3, 3))
    R[..., 0, 0] = 1.0
    R[..., 1, 1], R[..., 1, 2], R[..., 2, 1], R[..., 2, 2] = c, -s, s, c
    return R


def make(d):
    """Scene dict -> (scene, model)."""
    scene = parse_scene(to_toml(d))
    return scene, build_model(scene)


def tip_frequency(model, steps, scheme=None):
    """Angular frequency of a rod's tip motion in y over ``steps`` steps, from its zero crossings."""
    sim = Simulation(model, scheme=scheme)
    t, y = np.empty(steps), np.empty(steps)
    for i in range(steps):
        sim.step()
        t[i], y[i] = sim.state.t, sim.fields()["rod/r"][-1, 1]
    return zero_crossing_frequency(t, y)


def momentum_drift(sim, steps, every=1):
    """Largest changes of a Simulation's momenta over ``steps`` steps (monitors every ``every`` steps):
    (max |P - P0| L / |J0|, max |J - J0| / |J0|)."""
    m0 = sim.monitors()
    P0, J0 = m0["linear_momentum"], m0["angular_momentum"]
    scale = np.linalg.norm(J0)
    dP = dJ = 0.0
    for n in range(steps):
        sim.step()
        if n % every == every - 1:
            mo = sim.monitors()
            dP = max(dP, np.abs(mo["linear_momentum"] - P0).max() * sim.model.L / scale)
            dJ = max(dJ, np.abs(mo["angular_momentum"] - J0).max() / scale)
    return dP, dJ


def fail_newton_at(step, sizes, calls=None, after=0):
    """Make an energy-momentum step's Newton (``step._solve``) fail while the step size is one of ``sizes``: the
    attempts at each size numbered after+1 .. calls (counted from 1; ``calls=None``: all from after+1 on).  With
    after=0 and calls = the starts tried before varint.schemes.em_rod.halved_step, only those fail.  Attempts at other step
    sizes run as usual.  Returns the list of the sizes attempted."""
    from varint.errors import SolverError

    real, seen = step._solve, []
    sizes = np.atleast_1d(sizes).tolist()

    def solve(z, chord):
        seen.append(step.h)
        c = seen.count(step.h)
        if step.h in sizes and c > after and (calls is None or c <= calls):
            raise SolverError(f"step {step.n + 1}: induced failure")
        return real(z, chord)

    step._solve = solve
    return seen


# -- the declared invariants, checked on a run's monitors (tests/test_declared_invariants.py, test_capabilities.py)

#: momentum maps where a symmetry exists: round-off, relative to the momentum scale of the run
MOMENTUM_RTOL = 1e-12
#: the energy of the midpoint scheme is not an exact invariant of a nonlinear flow, but bounded; this is
#: a coarse bound for 30 steps (tests/test_examples.py bounds each example tightly)
ENERGY_RTOL = 2e-3


def energy_error_on_motion(sim, steps):
    """Step ``sim`` ``steps`` times; max abs(E - E0) over the run relative to the energy that moves (the largest
    kinetic energy plus the largest change of the potential, varint.run.io.energy_motion_scale: never |E0|, which a
    gas's internal energy dominates).  Returns (error, the last monitors)."""
    from varint.run.io import energy_motion_scale

    mons = [sim.monitors()]
    for _ in range(steps):
        sim.step()
        mons.append(sim.monitors())
    E = np.array([m["energy"] for m in mons])
    K = np.array([m["kinetic_energy"] for m in mons])
    return float(np.max(np.abs(E - E[0])) / energy_motion_scale(E, K)), mons[-1]


def _series(mons, key):
    return np.array([np.asarray(m[key], dtype=float) for m in mons])


def _gravity(model):
    g = getattr(model, "g", None)  # the rod's gravity vector
    if g is None:
        g = np.asarray(model.scene.environment.gravity, dtype=float)
    return np.asarray(g, dtype=float)


def _momentum_scale(model, mons):
    """Largest total |momentum| a run could show: the sum of the parts' magnitudes, or 1e-300."""
    P = _series(mons, "linear_momentum")
    J = _series(mons, "angular_momentum")
    return max(float(np.max(np.abs(P))), 1e-300), max(float(np.max(np.abs(J))), 1e-300)


def invariant_error(name, model, mons, fields):
    """(error, tolerance) of the declared invariant ``name`` over a run's monitors ``mons`` and fields ``fields``
    (lists, one entry per record); an invariant without a check here is an AssertionError."""
    E = _series(mons, "energy")
    # the energy that moves: the largest kinetic energy and each potential's variation over the run (never |E0|,
    # which a gas's internal energy or a liquid's p V dominates)
    kinetic = max(float(np.max(np.abs(_series(mons, "kinetic_energy")))), 0.0)
    pot = [k for k in mons[0] if k.startswith("energy_") and "kinetic" not in k]
    moving = kinetic + sum(float(np.ptp(_series(mons, k))) for k in pot)
    terms = [moving]
    Pscale, Jscale = _momentum_scale(model, mons)
    g = _gravity(model)
    ghat = g / np.linalg.norm(g) if np.any(g) else None
    P, J = _series(mons, "linear_momentum"), _series(mons, "angular_momentum")
    if name == "energy":
        return float(np.max(np.abs(E[1:] - E[1])) / max(max(terms), 1e-300)), ENERGY_RTOL
    if name == "mass":
        mass = _series(mons, "mass")
        return float(np.max(np.abs(mass - mass[0])) / mass[0]), 1e-13
    if name == "parcel_entropy":
        S = np.array([f["fluid/entropy"] for f in fields])
        return float(np.max(np.abs(S - S[0]))), 0.0
    if name in ("energy_balance", "momentum_balance", "mass_balance"):
        # open ends (docs/theory.md §13.4): now minus initial minus the boundary fluxes, against the largest
        # value or flux of its kind; energy: the midpoint rule's own error in a transient (ENERGY_RTOL)
        kind = name.split("_")[0]
        b = _series(mons, name)
        b = b[:, 0] if b.ndim > 1 else b
        value = {"energy": E, "momentum": P[:, 0], "mass": _series(mons, "mass")}[kind]
        flux = _series(mons, f"{kind}_flux")
        flux = flux[:, 0] if flux.ndim > 1 else flux
        ref = max(float(np.max(np.abs(value))), float(np.max(np.abs(flux))), 1e-300)
        # momentum: the balance is a difference of momenta summed with each step's end forces, so its rounding grows
        # with the steps (1.04e-12 after the capability cells' 4 steps of the open liquid); leaving the flux out
        # shows at 4.4e-6 there, 4000x this tolerance
        return float(np.max(np.abs(b))) / ref, {"energy": ENERGY_RTOL, "momentum": 10 * MOMENTUM_RTOL, "mass": 1e-13}[kind]
    if name == "parcel_volume":
        # where the scheme holds the volumes (the levels for a liquid on a [rod], docs/theory.md §10.12), to the
        # Newton tolerance
        return max(float(m.get("constraint_residual", 0.0)) for m in mons), 1e-9
    if name == "axial_momentum":
        return float(np.max(np.abs(P[:, 0] - P[0, 0])) / Pscale), MOMENTUM_RTOL
    if name == "linear_momentum":
        return float(np.max(np.linalg.norm(P - P[0], axis=1)) / Pscale), MOMENTUM_RTOL
    if name == "angular_momentum":
        return float(np.max(np.linalg.norm(J - J[0], axis=1)) / Jscale), MOMENTUM_RTOL
    if name == "linear_momentum_transverse_to_gravity":
        d = P - P[0]
        d -= np.outer(d @ ghat, ghat)
        return float(np.max(np.linalg.norm(d, axis=1)) / Pscale), MOMENTUM_RTOL
    if name == "angular_momentum_along_the_period":
        # a periodic rod (docs/theory.md §9): rotations about its period's axis, through the origin
        axis = np.asarray(model.rod.period, dtype=float) / np.linalg.norm(model.rod.period)
        return float(np.max(np.abs((J - J[0]) @ axis)) / Jscale), MOMENTUM_RTOL
    if name == "angular_momentum_along_gravity":
        return float(np.max(np.abs((J - J[0]) @ ghat)) / Jscale), MOMENTUM_RTOL
    if name == "angular_momentum_about_the_bearing_axis":
        # the line through the two pinned end nodes; the angular momentum about a point p0 on it is
        # J_0 - p0 x P (J_0 about the origin, P the momentum of the free components)
        p0, p1 = model.rod.r0[0], model.rod.r0[-1]
        axis = (p1 - p0) / np.linalg.norm(p1 - p0)
        Jp = J - np.cross(p0, P)
        return float(np.max(np.abs((Jp - Jp[0]) @ axis)) / Jscale), MOMENTUM_RTOL
    raise AssertionError(f"declared invariant {name!r} has no check in tests/helpers.py: add one")


def _release_from_mode(model, shape_of, amp=1e-4):
    """Start ``model``'s rod at rest in the first mode shape of ``shape_of`` (a rod model), tip amplitude ``amp``."""
    from varint.analysis.rod_modes import rod_modes

    _, X = rod_modes(shape_of, count=1, vectors=True)
    rod = model.rod
    u = np.zeros((model.N + 1, 6))
    u[rod.mask] = X[:, 0]
    u *= amp / np.max(np.abs(u[:, :3]))
    rod.set_configuration(rod.Lam0 @ cay(u[:, 3:]), rod.r0 + u[:, :3], rest=True)


def liquid_cantilever(N, h, R=0.01, L=1.0, rho_f=1000.0, scheme="midpoint"):
    """The water-filled cantilever of docs/theory.md §10.7a and the rod lattice with the liquid's mass rho_f A_f added
    to rho A (varint.scene.standard.liquid_cantilever_scenes), both released from the latter's first mode.  Returns
    (coupled, heavy, Timoshenko's first frequency with that mass)."""
    from varint.exact.beams import timoshenko_cantilever

    coupled_scene, heavy_scene = liquid_cantilever_scenes(N, h, R=R, L=L, rho_f=rho_f, scheme=scheme)
    coupled, heavy = build_model(coupled_scene), build_model(heavy_scene)
    _release_from_mode(heavy, heavy)
    _release_from_mode(coupled, heavy)
    r = heavy_scene.rod
    f_beam = timoshenko_cantilever(r.bending_stiffness, r.shear_stiffness, r.mass_per_length, r.rotary_inertia, L,
                                   count=1)[0]
    return coupled, heavy, f_beam


def shock_tube_fields(sim):
    """(labels s, density, pressure, velocity) of a straight tube's fluid, from the simulation's state."""
    m, st = sim.model, sim.state
    t = m.tube
    cfg = t.config(np.concatenate([st.q[m.tube_q], st.lam[m.tube_lam]]))
    rho, p, u = t.fluid_fields(cfg, st.p[m.tube_p])
    return cfg.s, rho, p, u


def run_to_end(d, check=None):
    """The Simulation of scene dict ``d`` run to its time.end; ``check(sim, state before the step)`` after each step."""
    sim = Simulation(make(d)[1])
    n = int(round(d["time"]["end"] / d["time"]["step"]))
    for _ in range(n):
        before = sim.state.copy()
        sim.step()
        if check is not None:
            check(sim, before)
    return sim


def read_only_dir(path):
    """A folder nobody can write into; as root (who ignores permissions), made immutable with chattr when it can be.
    Returns a function undoing it, or None when no read-only folder can be made here."""
    path.mkdir()
    path.chmod(stat.S_IRUSR | stat.S_IXUSR | stat.S_IRGRP | stat.S_IXGRP)
    probe = path / ".probe"
    try:
        probe.write_bytes(b"")
    except OSError:
        return lambda: path.chmod(0o755)
    probe.unlink()
    if shutil.which("chattr") and subprocess.run(["chattr", "+i", str(path)], capture_output=True).returncode == 0:
        try:
            probe.write_bytes(b"")
        except OSError:
            return lambda: (subprocess.run(["chattr", "-i", str(path)]), path.chmod(0o755))
        probe.unlink()
        subprocess.run(["chattr", "-i", str(path)])
    path.chmod(0o755)
    return None
