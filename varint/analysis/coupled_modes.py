"""Linear modes and statics of the coupled tube: rod + wall + fluid (docs/theory.md §10), linearised about its
initial state at rest or about its static equilibrium (:func:`coupled_static`).

The space-discrete Lagrangian of §10.4 (L_d as h -> 0) about a configuration q*,

    L = 1/2 qdot^T M(q*) qdot - 1/2 dq^T K dq,

in the model's step unknowns z (:class:`varint.model.model.Model`: the tube's labels, radii and multipliers, the
rod's (dr, sigma) on its support mask), with

* ``M`` the kinetic metric of §10.5 ("Initial momenta"): rho A w_j on the nodal velocities, the section
  inertia on the body angular velocities, a w_j on a dynamic wall's radial ones, and the fluid's
  1/2 sum_k mbar_k |sum_i N_i(s_k) rdot_i + X'_k sdot_k|^2, which couples nodes and labels
  (:func:`varint.terms.coupled.fluid_kinetic_metric`).  Sparse, symmetric positive definite on the
  inertial unknowns; the algebraic ones (multipliers mu, quasistatic radii) carry none.
* ``K`` the Hessian of the discrete potential in the retraction chart r + dr, Lambda cay(sigma), s, R, mu:
  the rod's exact element blocks (varint/model/statics.py ``force_jacobian``), the wall's terms
  (varint/terms/tube.py ``hessian``) and the fluid's (:func:`varint.terms.coupled.fluid_potential_static`:
  internal energy or incompressibility, p_ext on the stretched volume, gravity).

The algebraic unknowns are condensed as varint/analysis/linear.py ``linearization`` does where their block is
regular (a quasistatic wall); where it is singular — the multipliers of an incompressible fluid in a rigid
or dynamic wall (a zero block), or more parcels than a quasistatic wall has radii — its null space turns
the multipliers' rows into linearised volume constraints dV_k/dq dq = 0, and the problem is solved on the
constraints' null space (Z^T K Z, Z^T M Z; ``_reduce``).  The generalised eigenproblem K x = w^2 M x is
then solved densely (``scipy.linalg.eigh``: every mode) or, above :data:`DENSE_COUPLED_LIMIT` unknowns, by
shift-invert Lanczos on the whole pencil (``_sparse_modes``); negative w^2 beyond round-off are growth
rates, in the format of ``varint.analysis.linear.modes``.

Statics (:func:`coupled_static`) is Newton on the zero of the generalised force -dU/dz with the same K (the
saddle matrix, multipliers and quasistatic radii included) and load continuation, as varint/model/statics.py
does for the rod alone.  Not covered: spinning or moving initial states (steady rotations), a flowing fluid in a
closed tube, periodic fluid ends, the inextensible rod: each refused in one line.  A tube with open ends (a tube
conveying fluid, its gyroscopic and follower terms) is varint/analysis/flowing_modes.py's.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from ..errors import SolverError

__all__ = ["coupled_modes", "coupled_linearization", "modes_of_linearization", "coupled_static", "initial_configuration"]

#: above this many step unknowns the modes come from the sparse shift-invert solver (the dense one is O(n^3):
#: measured 1.6 s dense against 0.01 s sparse for a 3D gas tube of 100 elements, 800 unknowns)
DENSE_COUPLED_LIMIT = 1000


def _refuse(model):
    """One-line errors for the states this linearisation is not about (before any matrix is built)."""
    t, rod = model.tube, model.rod
    if t.open_ends:
        raise SolverError("modes: a tube with open fluid.ends (inflow/outflow) is linearised about its steady flow by "
                          "varint.analysis.flowing_modes (varint modes does so), not about a state at rest")
    if rod.constrained:
        raise SolverError("modes: the coupled tube with rod.constraint = \"inextensible_unshearable\" is not available "
                          "(the constrained rod's modes need its multipliers in the eigenproblem)")
    if t.periodic:
        raise SolverError("modes: the coupled tube with periodic fluid ends is not available")
    if np.any(rod.spin) or np.any(rod.velocity):
        raise SolverError("modes: the coupled tube is linearised about its initial state at rest: "
                          "rod.initial.velocity and rod.initial.angular_velocity must be zero")
    if np.any(t.v_init[t.layout["s"]] != 0.0):
        raise SolverError("modes: a closed coupled tube is linearised about its initial state at rest: the fluid must not "
                          "flow (fluid.velocity = 0); for the modes of a tube conveying fluid open its ends, "
                          "fluid.ends = { s0 = \"inflow\", sL = \"outflow\" } (docs/theory.md §13.6)")
    if t.wall_dynamic and np.any(t.v_init[t.layout["R"]] != 0.0):
        raise SolverError("modes: the coupled tube is linearised about its initial state at rest: the wall must not move")


def _fluid_term(model):
    """The model's fluid potential data and the map P from step unknowns z to the kernel ordering
    [rod 6/node | s | R | mu] (varint.terms.step.CoupledFluid's, with weight 1 on a quasistatic radius: in a
    static configuration it is the radius itself, not the half-level value of two levels)."""
    from ..terms.coupled import newton_offsets
    from ..terms.step import CoupledFluid

    cf = CoupledFluid(model)
    t = model.tube
    off, n = newton_offsets(model.rod.N + 1, t.M + 1, t.nR, t.M if t.incompressible else 0)
    scale = np.ones(n)
    scale[off["R"]:off["R"] + t.nR] = 1.0 / cf.R_weight
    return cf.fp, (sp.diags(scale) @ cf.P).tocsr(), off


def _embed(block, start, nz):
    block = sp.coo_matrix(block)
    return sp.csr_matrix((block.data, (block.row + start, block.col + start)), shape=(nz, nz))


def _names_and_units(model):
    """Block name of each step unknown and a typical displacement of it (translations ds, rotations 1, labels
    L/M, radii R0; multipliers 1): the scales of the force and convergence tests."""
    t, rod, nz = model.tube, model.rod, model.nz
    names = np.empty(nz, dtype=object)
    for name, idx in model.layout.items():
        names[np.arange(nz)[idx]] = name
    unit = np.ones(nz)
    unit[model.rod_z] = np.where(np.flatnonzero(rod.mask.ravel()) % 6 < 3, rod.ds, 1.0)
    unit[names == "s"] = t.L / t.M
    unit[names == "R"] = t.R0
    return names, unit


def _force_and_stiffness(model, Lam, r, zt, load_factor=1.0, stiffness=True, exact_rod=False):
    """The generalised force f = -dU/dz (nz) at a configuration (rod frames and positions, tube unknowns zt =
    (q, lam)), and the stiffness K = d^2U/dz^2 (sparse): the rod's exact element blocks (minus the derivative of
    its generalised force, rod_statics ``force_jacobian``; symmetrised unless ``exact_rod``, which keeps the
    derivative of the Lie gradient that Newton needs away from equilibrium), the wall's terms on the tube's
    blocks, the fluid's Hessian (:func:`varint.terms.coupled.fluid_potential_static`) mapped from its kernel
    ordering.  Gravity and the rod's end loads are scaled by ``load_factor``."""
    from dataclasses import replace

    from ..terms.coupled import fluid_potential_static
    from ..model.statics import force_jacobian, potential_gradient

    t, rod, nz = model.tube, model.rod, model.nz
    cfg = t.config(zt)
    fp, P, _ = _fluid_term(model)
    fp = replace(fp, g=load_factor * np.asarray(fp.g, dtype=float))
    _, gf, Hf = fluid_potential_static(fp, cfg.s, r, Lam, cfg.R, cfg.mu, hessian=stiffness)
    force = np.zeros(nz)
    force[model.rod_z] = potential_gradient(rod, Lam, r, load_factor)[rod.mask]
    force[model.tube_z] -= t.B.T @ t.gradient(cfg)
    force -= P.T @ gf
    if not stiffness:
        return force, None
    Kr = -force_jacobian(rod, Lam, r, load_factor)
    if not exact_rod:
        Kr = 0.5 * (Kr + Kr.T)
    K = _embed(Kr, model.rod_z.start, nz) + P.T @ Hf @ P
    Ht = t.hessian(cfg)
    if Ht.nnz:
        K = K + _embed(t.B.T @ Ht @ t.B, model.tube_z.start, nz)
    return force, K.tocsr()


def _mass(model, Lam, r, zt):
    """The kinetic metric of docs/theory.md §10.5 on the step unknowns (zero on the algebraic ones): the rod's
    lumped metric (weighted by |Gamma_e| under the paper's measure, as the stepper's level energy), a dynamic
    wall's a w_j, and the fluid's metric on (rdot, omega, sdot) mapped from the kernel ordering."""
    from ..terms.coupled import fluid_kinetic_metric
    from ..model.statics import lumped_mass

    t, rod, nz = model.tube, model.rod, model.nz
    cfg = t.config(zt)
    _, P, off = _fluid_term(model)
    lm = lumped_mass(rod)
    if rod.paper_measure:
        _, Ga = rod.strains(Lam, r)
        mu_e = np.linalg.norm(Ga, axis=1)
        wmu = np.zeros(rod.N + 1)
        wmu[:-1] += 0.5 * rod.ds * mu_e
        wmu[1:] += 0.5 * rod.ds * mu_e
        lm = lm * (wmu / rod.w)[:, None]
    M = _embed(sp.diags(lm[rod.mask]), model.rod_z.start, nz)
    M = M + _embed(sp.diags(np.concatenate([t.mass, np.zeros(t.nlam)])), model.tube_z.start, nz)
    Mf, _ = fluid_kinetic_metric(cfg.s, r, t.label_mass_all, t.ds)
    Pk = P[: off["R"]]  # the metric's ordering [rod 6/node | s]: the first rows of the kernel ordering
    M = M + Pk.T @ Mf @ Pk
    return (0.5 * (M + M.T)).tocsr()


def initial_configuration(model):
    """(Lambda, r, zt) of the scene's initial state: the rod's frames and positions, the tube's (q, lam)."""
    t = model.tube
    return model.rod.Lam0, model.rod.r0, np.concatenate([t.q_init, t.lam_init])


def coupled_linearization(model, configuration=None):
    """Mass and stiffness of the coupled tube about a configuration (default: its initial state), in the step
    unknowns z.

    ``configuration``: (Lambda, r, zt) as :func:`initial_configuration` or :func:`coupled_static` return.
    Returns a dict: ``M`` and ``K`` (sparse, nz x nz; M zero on the algebraic unknowns), ``inertial`` and
    ``algebraic`` (indices into z), ``names`` (block name of each z entry), ``force`` (the generalised force
    -dU/dz at the state, nz) and ``unbalanced`` (its largest entry over the elastic force of a unit strain:
    ~0 at an equilibrium).  See the module notes.
    """
    _refuse(model)
    t = model.tube
    Lam, r, zt = configuration if configuration is not None else initial_configuration(model)
    force, K = _force_and_stiffness(model, Lam, r, zt)
    M = _mass(model, Lam, r, zt)
    # the force's size against the elastic force of a unit strain (diag K x a unit displacement) says whether the
    # modes are about a loaded, unbalanced state (gravity, end loads, a closed tube's pressure thrust against p_ext)
    names, unit = _names_and_units(model)
    algebraic = model.tube_z.start + np.arange(t.nq, t.nq + t.nlam)
    inertial = np.setdiff1d(np.arange(model.nz), algebraic)
    forced = names != "mu"  # (a multiplier's row is a volume, not a force)
    size = float(np.max(np.abs(K.diagonal()[forced]) * unit[forced]))
    unbalanced = float(np.max(np.abs(force[forced]))) / size if size > 0 else 0.0
    return {"M": M, "K": K, "inertial": inertial, "algebraic": algebraic, "names": names, "force": force,
            "unbalanced": unbalanced}


def coupled_static(model, steps=4, tol=1e-10, max_iter=40):
    """The static equilibrium of the coupled tube: Newton on the zero of the generalised force in every block at
    once (rod on SE(3)^(N+1) by Lambda cay(sigma), r + dr; labels; radii; multipliers: K dz = f, K the saddle
    matrix of :func:`_force_and_stiffness`), with load continuation in gravity and the rod's end loads as
    varint/model/statics.py ``static_equilibrium`` (``steps`` increments, doubled until each converges).
    Converged when every increment is below ``tol`` of its block's typical displacement (multipliers: of the
    largest |mu| or p_ext).  Returns ((Lambda, r, zt), info); a free tube (no unique equilibrium) and the states
    :func:`coupled_linearization` refuses are one-line errors.
    """
    import warnings

    import scipy.sparse.linalg as spla

    from ..model.statics import retract, load_continuation

    _refuse(model)
    t, rod = model.tube, model.rod
    if rod.free:
        raise SolverError("static equilibrium: with both rod.ends free the coupled tube can move rigidly, so it has "
                          "no unique static equilibrium; clamp or pin an end")
    names, unit = _names_and_units(model)
    mu_idx = names == "mu"
    mask = rod.mask
    start = initial_configuration(model)

    def newton_step(state, lf):
        Lam, r, zt = state
        f, K = _force_and_stiffness(model, Lam, r, zt, lf, exact_rod=True)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", spla.MatrixRankWarning)
            dz = spla.spsolve(K.tocsc(), f)
        if not np.all(np.isfinite(dz)):
            return state, None
        Lam, r = retract(Lam, r, dz[model.rod_z], mask)
        zt = zt + dz[model.tube_z]
        if t.label_problem(t.config(zt)) is not None:
            return state, None
        scale = unit.copy()
        if np.any(mu_idx):
            scale[mu_idx] = max(float(np.max(np.abs(zt[t.layout["mu"]]))), t.p_ext, 1.0)
        return (Lam, r, zt), bool(np.max(np.abs(dz) / scale) < tol)

    state, n_steps, iters = load_continuation(lambda: tuple(x.copy() for x in start), newton_step, steps, max_iter)
    return state, {"load_steps": n_steps, "iterations": iters}


def _reduce(lin):
    """(K_r, M_r, back) on the inertial unknowns, with the algebraic ones condensed: back(y) gives the
    whole z-vector of a reduced mode shape y."""
    K = lin["K"].toarray()
    M = lin["M"].toarray()
    q, lam = lin["inertial"], lin["algebraic"]
    Kqq, Mqq = K[np.ix_(q, q)], M[np.ix_(q, q)]
    nz = K.shape[0]
    if len(lam) == 0:
        def back(y):
            z = np.zeros((nz,) + y.shape[1:])
            z[q] = y
            return z
        return Kqq, Mqq, back
    Kql, Kll = K[np.ix_(q, lam)], K[np.ix_(lam, lam)]
    # Split the algebraic block into its regular part and its null space.  With D an equilibrating scaling
    # (radii and multipliers have unrelated units), D Kll D = V diag(d) V^T; directions with |d| below 1e-10 of
    # the largest are the null space N (the multipliers of an incompressible fluid in a rigid or dynamic wall,
    # whose block is zero; with a quasistatic wall the parcels beyond the radii's reach, M > nR).  Then
    #   lam = -Kll^+ Klq q + N alpha,   N^T Klq q = 0 (the linearised volume constraints),
    # and the inertial motion lives on the null space Z of C = N^T Klq with the condensed stiffness
    #   Z^T (Kqq - Kql Kll^+ Klq) Z   (alpha drops out: Z^T Kql N = (C Z)^T = 0).
    rows = np.max(np.abs(Kll), axis=1)
    D = np.where(rows > 0, 1.0 / np.sqrt(np.where(rows > 0, rows, 1.0)), 1.0)
    d, V = np.linalg.eigh(D[:, None] * Kll * D[None, :])
    big = np.max(np.abs(d)) if len(d) else 0.0
    reg = np.abs(d) > 1e-10 * big if big > 0 else np.zeros(len(d), bool)
    Vr = D[:, None] * V[:, reg]                 # Kll^+ = Vr diag(1/d) Vr^T (in the unscaled unknowns)
    S = Vr @ ((Vr.T @ Kql.T) / d[reg][:, None])  # Kll^+ Klq
    Kc = Kqq - Kql @ S
    N = D[:, None] * V[:, ~reg]
    if N.shape[1]:
        Z = sla.null_space(N.T @ Kql.T, rcond=1e-10)
    else:
        Z = np.eye(len(q))

    def back(y):
        z = np.zeros((nz,) + y.shape[1:])
        xq = Z @ y
        z[q] = xq
        z[lam] = -S @ xq  # (the multipliers' null-space part alpha is not recovered)
        return z
    Kr = Z.T @ Kc @ Z
    Mr = Z.T @ Mqq @ Z
    return 0.5 * (Kr + Kr.T), 0.5 * (Mr + Mr.T), back


def coupled_modes(model, count=20, vectors=False, method="auto"):
    """The ``count`` lowest modes of the coupled tube linearised about its initial state at rest.

    Returns ``[{"frequency": rad/s, "growth_rate": 1/s}, ...]`` in the order of ``varint.analysis.linear.modes``
    (instabilities first, then frequencies increasing); with ``vectors`` also the mode shapes (nz, count)
    in the model's step unknowns z (algebraic entries: the condensed radii and the regular part of the
    multipliers).  ``method``: "dense" (every mode), "sparse" (the lowest ``count`` by shift-invert Lanczos)
    or "auto" (sparse above :data:`DENSE_COUPLED_LIMIT` unknowns).  Raises
    :class:`varint.errors.SolverError` (one line) for states it does not linearise about.
    """
    return modes_of_linearization(model, coupled_linearization(model), count, vectors, method)


def modes_of_linearization(model, lin, count=20, vectors=False, method="auto"):
    """:func:`coupled_modes` of a :func:`coupled_linearization` already built (``varint modes`` also reads
    its ``unbalanced``)."""
    from .linear import _modes_from_w2

    if method == "sparse" or (method == "auto" and lin["K"].shape[0] > DENSE_COUPLED_LIMIT):
        return _sparse_modes(lin, count, vectors)
    Kr, Mr, back = _reduce(lin)
    if Kr.shape[0] == 0:
        return ([], np.zeros((model.nz, 0))) if vectors else []
    w2, X = sla.eigh(Kr, Mr)
    # the threshold of varint.analysis.linear.modes_of: negative w^2 below 1e-14 of the largest |w^2| is round-off
    res = _modes_from_w2(w2[:count], 1e-14 * max(abs(w2[-1]), abs(w2[0]), 1e-300))
    if vectors:
        return res, back(X[:, :count])
    return res


def _sparse_modes(lin, count, vectors):
    """The lowest ``count`` modes by shift-invert Lanczos on the whole pencil (K, M) in z.

    M is only semi-definite (zero on the algebraic unknowns), which ARPACK's shift-invert mode accepts: the
    operator (K - sigma M)^-1 M maps the algebraic directions and the constrained ones to the eigenvalue 0 of
    an infinite w^2, never near the shift, so what it returns are the finite modes of the condensed problem;
    K - sigma M is the regular saddle matrix of the step (sparse LU).  The shift sits just below zero, as in
    varint.analysis.linear.sparse_modes_of (1e-8, then 1e-14, of a Gershgorin bound on the largest w^2 from the
    inertial rows); the classification threshold is 1e-18 of that bound on w^2.  Mode shapes: the z-vectors
    themselves (multipliers included).
    """
    import scipy.sparse.linalg as spla

    from .linear import SPARSE_SHIFTS, _arpack, _modes_from_w2

    K, M = lin["K"].tocsc(), lin["M"].tocsc()
    q = lin["inertial"]
    rows = np.asarray(abs(K[q]).sum(axis=1)).ravel()
    big2 = float(np.max(rows / M.diagonal()[q]))
    k = min(count, len(q) - 2)
    for i, shift in enumerate(SPARSE_SHIFTS):
        try:
            w2, X = _arpack(spla.eigsh, K, k=k, M=M, sigma=-shift * big2, which="LM", v0=np.ones(K.shape[0]),
                            maxiter=300 if i < len(SPARSE_SHIFTS) - 1 else None)
            break
        except Exception:  # noqa: BLE001 (ARPACK's failure as a VarintError; the last shift re-raises)
            if i == len(SPARSE_SHIFTS) - 1:
                raise
    order = np.argsort(w2)
    res = _modes_from_w2(w2[order], 1e-18 * big2)
    return (res, X[:, order]) if vectors else res
