"""The residual Newton drives to zero is the gradient of the discrete action (docs/theory.md §4).

Every check has a tolerance relative to the quantity checked, so that a small force cannot hide
under a large one (in 0.1 one absolute tolerance per block, set by the pressure forces, let the
whole gravity force go unnoticed):

* each potential term of the model (:mod:`varint.terms.tube_potential`): its gradient against central finite
  differences of its own energy and its Hessian against finite differences of its own gradient,
  relative to that term's own size, block by block;
* the step residual: for a short random lattice trajectory q_0, q_1, q_2 (and half-level
  algebraic unknowns lam_{1/2}, lam_{3/2}) the action S = L_d(q_0, q_1, lam_{1/2}) + L_d(q_1, q_2, lam_{3/2})
  is split into its kinetic part and one part per term; the residual of each part must equal the
  finite-difference gradient of that part with respect to q_1 and lam_{3/2}, relative to the part's
  own size; the parts must add up to the residual the stepper solves, and that residual must equal
  the gradient of the whole action relative to the largest part.

The Jacobian Newton uses is checked against finite differences of the residual.
"""

import itertools
from contextlib import contextmanager

import numpy as np
import pytest

from varint.schemes.midpoint import make_scheme

from varint.scene.standard import AIR, gas_scene
from helpers import make

#: gravity along the tube axis in every scene with a fluid [m/s^2]
G_X = 9.81

WALLS = {
    "rigid": None,
    "rigid-table": "table",
    "dynamic-linear": {"model": "dynamic", "law": "linear", "a": 0.5, "beta1": 400.0, "beta2": 8e5},
    "dynamic-tubelaw": {"model": "dynamic", "law": "tube-law", "a": 0.5, "stiffness": 1e5, "tension": 0.3},
    "quasistatic-linear": {"model": "quasistatic", "law": "linear", "beta1": 400.0, "beta2": 8e5},
    "quasistatic-tubelaw": {"model": "quasistatic", "law": "tube-law", "stiffness": 1e5, "tension": 0.3},
}
FLUIDS = {
    "ideal-gas": dict(AIR),
    "barotropic": {"model": "barotropic", "density": 1000.0, "pressure": 1e5, "bulk_modulus": 2e6, "gamma": 7.15},
    "incompressible": {"model": "incompressible", "density": 1000.0, "pressure": 1e5},
    "none": None,
}


def _scene(wall, fluid, ends, scheme, gravity):
    d = gas_scene(nodes=9, parcels=7, ends=ends, scheme=scheme, h=1e-4)
    if fluid is None:
        del d["fluid"]
    else:
        d["fluid"] = dict(fluid, parcels=7, ends={"s0": ends, "sL": ends})
    if wall is None:
        d.pop("wall", None)
    elif wall == "table":
        d.pop("wall", None)
        d["tube"]["area_table"] = [[0.0, 0.006], [0.5, 0.009], [1.0, 0.007]]
    else:
        d["wall"] = dict(wall, perturbation=[{"field": "R", "shape": "cosine", "amplitude": 0.002, "wavelength": 1.0}])
    d["environment"] = {"external_pressure": 9.5e4, "gravity": [gravity, 0.0, 0.0]}
    return d


def _combos(schemes=("midpoint", "trapezoidal")):
    for (wn, w), (fn, f), ends, scheme in itertools.product(WALLS.items(), FLUIDS.items(), ["closed", "periodic"],
                                                            schemes):
        if f is None and (w is None or w == "table" or ends == "periodic"):
            continue  # nothing moves, or periodicity is a property of the fluid's ends
        if fn == "incompressible" and (w is None or w == "table"):
            continue  # refused by the scene validator
        if w == "table" and ends == "periodic":
            continue
        algebraic = fn == "incompressible" or (isinstance(w, dict) and w["model"] == "quasistatic")
        if scheme == "trapezoidal" and algebraic:
            continue  # refused by the scene validator (tested in test_scene)
        yield pytest.param(w, f, ends, scheme, id=f"{wn}-{fn}-{ends}-{scheme}")


def _model(wall, fluid, ends, scheme, gravity=G_X):
    _, model = make(_scene(wall, fluid, ends, scheme, gravity=gravity if fluid is not None else 0.0))
    if fluid is not None and gravity != 0.0:
        # the scene's gravity must reach the model as a force term (checked against its energy below)
        assert "gravity" in [t.name for t in model.tube.terms]
    return model


def _scales(model):
    sc = np.ones(model.nz)
    for name, sl in model.layout.items():
        sc[sl] = {"s": model.L / max(model.tube.M, 1), "R": model.tube.R0, "mu": 1e4}[name]
    return sc


def _config_blocks(model):
    """Configuration-space blocks (s, R, mu) that some unknown moves, with their scales."""
    moved = np.asarray(abs(model.tube.B).sum(axis=1)).ravel() > 0
    i = model.tube.index
    ends = {"s": (0, i["R"]), "R": (i["R"], i["R"] + model.tube.nR), "mu": (i["mu"], model.tube.nconfig)}
    scale = {"s": model.L / max(model.tube.M, 1), "R": model.tube.R0, "mu": 1e4}
    out = {}
    for name, (a, b) in ends.items():
        idx = np.arange(a, b)[moved[a:b]]
        if len(idx):
            out[name] = (idx, scale[name])
    return out


def _term_gradient(term, cfg, model):
    gs = np.zeros(model.tube.index["R"])
    gR = np.zeros(model.tube.nR)
    gmu = np.zeros(model.tube.M if model.tube.incompressible else 0)
    term.gradient(cfg, {}, gs, gR, gmu)
    return np.concatenate([gs, gR, gmu])


def _with(cfg, model, c):
    i = model.tube.index
    return type(cfg)(c[: i["R"]].copy(), c[i["R"]: i["R"] + model.tube.nR].copy(),
                     c[i["mu"]:].copy() if model.tube.incompressible else None)


@pytest.mark.parametrize("wall,fluid,ends,scheme", list(_combos(schemes=("midpoint",))))
def test_each_term_force_is_the_gradient_of_its_own_energy(wall, fluid, ends, scheme):
    """Term by term, block by block: gradient vs FD of the energy, Hessian vs FD of the gradient, each to
    1e-6 of that term's own largest entry in the block (gravity's force is checked against gravity's energy,
    not against the pressure forces)."""
    model = _model(wall, fluid, ends, scheme)
    rng = np.random.default_rng(11)
    z = np.concatenate([model.tube.q_init, model.tube.lam_init]) + 0.05 * _scales(model) * rng.standard_normal(model.nz)
    cfg = model.tube.config(z)
    c0 = np.concatenate([cfg.s, cfg.R, cfg.mu if model.tube.incompressible else np.empty(0)])
    blocks = _config_blocks(model)
    names = [t.name for t in model.tube.terms]
    assert len(set(names)) == len(names)
    for term in model.tube.terms:
        g = _term_gradient(term, cfg, model)
        r, c, v = term.hessian(cfg, {}, model.tube.index)
        H = np.zeros((model.tube.nconfig, model.tube.nconfig))
        np.add.at(H, (r, c), v)
        for bname, (idx, sc) in blocks.items():
            fd = np.empty(len(idx))
            Hfd = np.empty((model.tube.nconfig, len(idx)))
            for j, i in enumerate(idx):
                cp, cm = c0.copy(), c0.copy()
                cp[i] += 1e-5 * sc
                cm[i] -= 1e-5 * sc
                fd[j] = (term.energy(_with(cfg, model, cp), {}) - term.energy(_with(cfg, model, cm), {})) / (2e-5 * sc)
                cp, cm = c0.copy(), c0.copy()
                cp[i] += 1e-6 * sc
                cm[i] -= 1e-6 * sc
                Hfd[:, j] = (_term_gradient(term, _with(cfg, model, cp), model)
                             - _term_gradient(term, _with(cfg, model, cm), model)) / (2e-6 * sc)
            where = f"{term.name}: d/d{bname}"
            if bname not in term.touches:
                assert np.all(g[idx] == 0.0) and np.all(fd == 0.0), where
            ref = np.abs(fd).max()
            assert np.allclose(g[idx], fd, rtol=0, atol=1e-6 * ref), (where, np.abs(g[idx] - fd).max() / max(ref, 1e-300))
            for rname, (ridx, _) in blocks.items():
                Hb, Fb = H[np.ix_(ridx, idx)], Hfd[ridx]
                href = np.abs(Fb).max()
                assert np.allclose(Hb, Fb, rtol=0, atol=1e-6 * href), (f"{term.name}: d2/d{rname}d{bname}",
                                                                       np.abs(Hb - Fb).max() / max(href, 1e-300))
    if fluid is not None:
        # gravity's force on each label is -m_k g_x: a constant, independent of the configuration
        grav = next(t for t in model.tube.terms if t.name == "gravity")
        idx = blocks["s"][0]
        assert np.allclose(_term_gradient(grav, cfg, model)[idx], -G_X * model.tube.label_mass_config[idx], rtol=1e-15, atol=0)


@contextmanager
def _part(model, S, terms, kinetic):
    """The model and step reduced to one part of the action: the kinetic term, or one potential term."""
    saved_terms, saved_step_terms = model.tube.terms, S.terms
    model.tube.terms = list(terms)
    if not kinetic:
        S.terms = [t for t in S.terms if t.name != "tube_kinetic"]
    try:
        yield
    finally:
        model.tube.terms, S.terms = saved_terms, saved_step_terms


@pytest.mark.parametrize("wall,fluid,ends,scheme", list(_combos()))
def test_residual_is_gradient_of_discrete_action(wall, fluid, ends, scheme):
    model = _model(wall, fluid, ends, scheme)
    S = make_scheme(model, 1e-4, scheme)
    rng = np.random.default_rng(42)
    nq, nl = model.tube.nq, model.tube.nlam
    scale = _scales(model)
    z0 = np.concatenate([model.tube.q_init, model.tube.lam_init])
    q = [z0[:nq] + 0.05 * scale[:nq] * rng.standard_normal(nq) for _ in range(3)]
    lam = [z0[nq:] + 0.05 * scale[nq:] * rng.standard_normal(nl) for _ in range(2)]

    def action(q1, lam1):
        return S.discrete_lagrangian(q[0], q1, lam[0]) + S.discrete_lagrangian(q1, q[2], lam1)

    def residual():
        p1 = S.momentum_plus(q[0], np.concatenate([q[1], lam[0]]))
        return S.residual(q[1], p1, np.concatenate([q[2], lam[1]]))

    def fd_action(step):
        fd = np.empty(nq + nl)
        for i in range(nq + nl):
            e = step * scale[i]
            if i < nq:
                dq = np.zeros(nq)
                dq[i] = e
                fd[i] = (action(q[1] + dq, lam[1]) - action(q[1] - dq, lam[1])) / (2 * e)
            else:
                dl = np.zeros(nl)
                dl[i - nq] = e
                fd[i] = (action(q[1], lam[1] + dl) - action(q[1], lam[1] - dl)) / (2 * e)
        return fd

    r = residual()
    parts = {"kinetic": ([], True)} | {t.name: ([t], False) for t in model.tube.terms}
    r_parts, sizes = {}, {name: 0.0 for name in model.layout}
    for pname, (terms, kinetic) in parts.items():
        with _part(model, S, terms, kinetic):
            rp, fd = residual(), fd_action(1e-5)
        r_parts[pname] = rp
        for name, sl in model.layout.items():
            ref = np.abs(fd[sl]).max()
            sizes[name] = max(sizes[name], ref)
            assert np.allclose(rp[sl], fd[sl], rtol=0, atol=1e-6 * ref), (pname, name, np.abs(rp[sl] - fd[sl]).max() / max(ref, 1e-300))
    fd = fd_action(1e-4)
    total = sum(r_parts.values())
    # compare block by block (the blocks have different units), relative to the largest part of each
    for name, sl in model.layout.items():
        assert np.allclose(r[sl], total[sl], rtol=0, atol=1e-12 * sizes[name]), name
        assert np.allclose(r[sl], fd[sl], rtol=0, atol=2e-6 * sizes[name]), name
    if fluid is not None:
        # gravity's part of the residual is the impulse -h m_k g_x on each label, not lost under the pressure forces
        sl = model.layout["s"]
        lab = model.tube.mass[sl]
        assert np.allclose(r_parts["gravity"][sl], S.h * G_X * lab, rtol=1e-12, atol=0)


@pytest.mark.parametrize("wall,fluid,ends,scheme", [p for p in _combos() if "midpoint" in p.id and "closed" in p.id])
def test_jacobian_is_derivative_of_residual(wall, fluid, ends, scheme):
    model = _model(wall, fluid, ends, scheme, gravity=0.0)
    S = make_scheme(model, 1e-4, scheme)
    rng = np.random.default_rng(7)
    scale = _scales(model)
    z0 = np.concatenate([model.tube.q_init, model.tube.lam_init])
    qn = model.tube.q_init + 0.05 * scale[:model.tube.nq] * rng.standard_normal(model.tube.nq)
    z = z0 + 0.05 * scale * rng.standard_normal(model.nz)
    pn = rng.standard_normal(model.tube.nq) * 1e-3
    J = S.jacobian(qn, z).toarray()
    Jfd = np.empty_like(J)
    for i in range(model.nz):
        e = np.zeros(model.nz)
        e[i] = 1e-6 * scale[i]
        Jfd[:, i] = (S.residual(qn, pn, z + e) - S.residual(qn, pn, z - e)) / (2 * e[i])
    assert np.allclose(J, Jfd, atol=1e-6 * np.abs(J).max(), rtol=1e-5)
