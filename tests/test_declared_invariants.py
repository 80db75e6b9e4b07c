"""Every example keeps the invariants its model declares (`varint check` lists them).

The declarations come from the terms (what each keeps or breaks) and the ends; this test runs each
example scene and checks every declared invariant with the monitor that measures it.  An invariant
name without a check here fails the test, so a new declaration cannot go unchecked, and a term that
declares a symmetry it does not keep is caught on the examples that use it.
"""

from pathlib import Path

import numpy as np
import pytest

import varint

EXAMPLES = sorted((Path(__file__).resolve().parent.parent / "examples").glob("*.toml"))
STEPS = 30
#: momentum maps where a symmetry exists: round-off, relative to the momentum scale of the run
MOMENTUM_RTOL = 1e-12
#: the energy of the midpoint scheme is not an exact invariant of a nonlinear flow, but bounded; this is
#: a coarse bound for 30 steps (tests/test_examples.py bounds each example tightly)
ENERGY_RTOL = 2e-3


def _run(path):
    model = varint.build_model(varint.load_scene(path))
    sim = varint.make_simulation(model)
    declared = model.describe()["invariants"]
    mons, fields = [sim.monitors()], [sim.fields()]
    for _ in range(STEPS):
        sim.step()
        mons.append(sim.monitors())
        fields.append(sim.fields())
    return model, declared, mons, fields


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


def _check(name, model, mons, fields):
    E = _series(mons, "energy")
    terms = [abs(float(v)) for m in mons for k, v in m.items() if k.startswith("energy_") or k == "kinetic_energy"]
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
        return float(np.max(np.abs(b))) / ref, {"energy": ENERGY_RTOL, "momentum": MOMENTUM_RTOL, "mass": 1e-13}[kind]
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
    if name == "angular_momentum_along_gravity":
        return float(np.max(np.abs((J - J[0]) @ ghat)) / Jscale), MOMENTUM_RTOL
    if name == "angular_momentum_about_the_bearing_axis":
        # the line through the two pinned end nodes; the angular momentum about a point p0 on it is
        # J_0 - p0 x P (J_0 about the origin, P the momentum of the free components)
        p0, p1 = model.rod.r0[0], model.rod.r0[-1]
        axis = (p1 - p0) / np.linalg.norm(p1 - p0)
        Jp = J - np.cross(p0, P)
        return float(np.max(np.abs((Jp - Jp[0]) @ axis)) / Jscale), MOMENTUM_RTOL
    raise AssertionError(f"declared invariant {name!r} has no check in {Path(__file__).name}: add one")


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.stem)
def test_examples_keep_their_declared_invariants(path):
    model, declared, mons, fields = _run(path)
    assert declared, f"{path.name}: no invariant declared"
    failures = []
    for name in declared:
        err, tol = _check(name, model, mons, fields)
        if not err <= tol:
            failures.append(f"{name}: {err:.3g} > {tol:g}")
    assert not failures, f"{path.name}: " + "; ".join(failures)


def test_a_false_declaration_is_caught():
    """The check is not vacuous: declaring linear momentum on a rod whose tip is loaded (momentum grows
    by the load's impulse every step) makes it fail."""
    path = next(p for p in EXAMPLES if p.stem == "cantilever_rod")
    model, _, mons, fields = _run(path)
    err, tol = _check("linear_momentum", model, mons, fields)
    assert err > 1e3 * tol
    with pytest.raises(AssertionError, match="no check"):
        _check("vorticity", model, mons, fields)
