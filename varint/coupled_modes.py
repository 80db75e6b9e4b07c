"""Linear modes of the coupled tube: rod + wall + fluid linearised about its initial state (docs/theory.md §10).

The space-discrete Lagrangian of §10.4 (L_d as h -> 0) about a configuration q*,

    L = 1/2 qdot^T M(q*) qdot - 1/2 dq^T K dq,

in the model's step unknowns z (:class:`varint.model.Model`: the tube's labels, radii and multipliers, the
rod's (dr, sigma) on its support mask), with

* ``M`` the kinetic metric of §10.5 ("Initial momenta"): rho A w_j on the nodal velocities, the section
  inertia on the body angular velocities, a w_j on a dynamic wall's radial ones, and the fluid's
  1/2 sum_k mbar_k |sum_i N_i(s_k) rdot_i + X'_k sdot_k|^2, which couples nodes and labels
  (:func:`varint.coupled_terms.fluid_kinetic_metric`).  Sparse, symmetric positive definite on the
  inertial unknowns; the algebraic ones (multipliers mu, quasistatic radii) carry none.
* ``K`` the Hessian of the discrete potential in the retraction chart r + dr, Lambda cay(sigma), s, R, mu:
  the rod's exact element blocks (varint/rod_statics.py ``_force_jacobian``), the wall's terms
  (varint/tube.py ``hessian``) and the fluid's (:func:`varint.coupled_terms.fluid_potential_static`:
  internal energy or incompressibility, p_ext on the stretched volume, gravity).

The algebraic unknowns are condensed as varint/analysis.py ``linearization`` does where their block is
regular (a quasistatic wall); where it is singular — the multipliers of an incompressible fluid in a rigid
or dynamic wall (a zero block), or more parcels than a quasistatic wall has radii — its null space turns
the multipliers' rows into linearised volume constraints dV_k/dq dq = 0, and the problem is solved on the
constraints' null space (Z^T K Z, Z^T M Z; ``_reduce``).  The
generalised eigenproblem K x = w^2 M x is then solved densely (``scipy.linalg.eigh``: every mode),
negative w^2 beyond round-off reported as growth rates, in the format of ``varint.analysis.modes``.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from .errors import SolverError

__all__ = ["coupled_modes", "coupled_linearization", "modes_of_linearization"]

#: the dense eigen-solver's limit on the unknowns left after condensation (O(n^3) time, O(n^2) memory)
DENSE_COUPLED_LIMIT = 4000


def _refuse(model):
    """One-line errors for the states this linearisation is not about (before any matrix is built)."""
    t, rod = model.tube, model.rod
    if rod.constrained:
        raise SolverError("modes: the coupled tube with rod.constraint = \"inextensible_unshearable\" is not available "
                          "(the constrained rod's modes need its multipliers in the eigenproblem)")
    if t.periodic:
        raise SolverError("modes: the coupled tube with periodic fluid ends is not available")
    if np.any(rod.spin) or np.any(rod.velocity):
        raise SolverError("modes: the coupled tube is linearised about its initial state at rest: "
                          "rod.initial.velocity and rod.initial.angular_velocity must be zero")
    if np.any(t.v_init[t.layout["s"]] != 0.0):
        raise SolverError("modes: the coupled tube is linearised about its initial state at rest: the fluid must not "
                          "flow (fluid.velocity = 0); modes of a flowing tube are not available in this version")
    if t.wall_dynamic and np.any(t.v_init[t.layout["R"]] != 0.0):
        raise SolverError("modes: the coupled tube is linearised about its initial state at rest: the wall must not move")


def _fluid_term(model):
    """The model's fluid potential data and the map P from step unknowns z to the kernel ordering
    [rod 6/node | s | R | mu] (varint.step_terms.CoupledFluid's, with weight 1 on a quasistatic radius: in a
    static configuration it is the radius itself, not the half-level value of two levels)."""
    from .coupled_terms import newton_offsets
    from .step_terms import CoupledFluid

    cf = CoupledFluid(model)
    t = model.tube
    off, n = newton_offsets(model.rod.N + 1, t.M + 1, t.nR, t.M if t.incompressible else 0)
    scale = np.ones(n)
    scale[off["R"]:off["R"] + t.nR] = 1.0 / cf.R_weight
    return cf.fp, (sp.diags(scale) @ cf.P).tocsr(), off


def coupled_linearization(model):
    """Mass and stiffness of the coupled tube about its initial state, in the step unknowns z.

    Returns a dict: ``M`` and ``K`` (sparse, nz x nz; M zero on the algebraic unknowns), ``inertial`` and
    ``algebraic`` (indices into z), ``names`` (block name of each z entry), ``force`` (the generalised force
    -dU/dz at the state, nz) and ``unbalanced`` (its largest entry over the elastic force of a unit strain:
    ~0 at an equilibrium).  See the module notes.
    """
    from .coupled_terms import fluid_kinetic_metric, fluid_potential_static
    from .rod_statics import _force_jacobian, lumped_mass

    _refuse(model)
    t, rod = model.tube, model.rod
    nz = model.nz
    cfg = t.config(np.concatenate([t.q_init, t.lam_init]))
    Lam, r = rod.Lam0, rod.r0
    fp, P, off = _fluid_term(model)

    def embed(block, start):
        block = sp.coo_matrix(block)
        return sp.csr_matrix((block.data, (block.row + start, block.col + start)), shape=(nz, nz))

    # stiffness: the rod's exact element Hessian (minus the derivative of its generalised force), the wall's
    # terms on the tube's blocks, and the fluid's Hessian mapped from its kernel ordering
    K = embed(-_force_jacobian(rod, Lam, r), model.rod_z.start)
    Ht = t.hessian(cfg)
    if Ht.nnz:
        K = K + embed(t.B.T @ Ht @ t.B, model.tube_z.start)
    _, _, Hf = fluid_potential_static(fp, cfg.s, r, Lam, cfg.R, cfg.mu)
    K = K + P.T @ Hf @ P
    K = (0.5 * (K + K.T)).tocsr()

    # mass: the rod's lumped metric (weighted by |Gamma_e| under the paper's measure, as the stepper's level
    # energy), the dynamic wall's a w_j, and the fluid's metric on (rdot, omega, sdot)
    lm = lumped_mass(rod)
    if rod.paper_measure:
        _, Ga = rod.strains(Lam, r)
        mu_e = np.linalg.norm(Ga, axis=1)
        wmu = np.zeros(rod.N + 1)
        wmu[:-1] += 0.5 * rod.ds * mu_e
        wmu[1:] += 0.5 * rod.ds * mu_e
        lm = lm * (wmu / rod.w)[:, None]
    M = embed(sp.diags(lm[rod.mask]), model.rod_z.start)
    tube_mass = np.concatenate([t.mass, np.zeros(t.nlam)])
    M = M + embed(sp.diags(tube_mass), model.tube_z.start)
    Mf, _ = fluid_kinetic_metric(cfg.s, r, t.label_mass_all, t.ds)
    Pk = P[: off["R"]]  # the metric's ordering [rod 6/node | s]: the first rows of the kernel ordering
    M = (M + Pk.T @ Mf @ Pk).tocsr()
    M = 0.5 * (M + M.T)

    # the generalised force -dU/dz at the state (rod, wall, fluid): zero at an equilibrium.  Its size against the
    # elastic force of a unit strain (diag K x a unit displacement) says whether the modes are about a loaded,
    # unbalanced state (gravity, end loads, a closed tube's pressure thrust against p_ext)
    from .rod_statics import _potential_gradient

    force = np.zeros(nz)
    force[model.rod_z] = _potential_gradient(rod, Lam, r)[rod.mask]
    force[model.tube_z] -= t.B.T @ t.gradient(cfg)
    force -= P.T @ fluid_potential_static(fp, cfg.s, r, Lam, cfg.R, cfg.mu, hessian=False)[1]

    names = np.empty(nz, dtype=object)
    for name, idx in model.layout.items():
        names[np.arange(nz)[idx]] = name
    algebraic = model.tube_z.start + np.arange(t.nq, t.nq + t.nlam)
    inertial = np.setdiff1d(np.arange(nz), algebraic)
    unit = np.ones(nz)
    unit[model.rod_z] = np.where(np.flatnonzero(rod.mask.ravel()) % 6 < 3, rod.ds, 1.0)
    unit[names == "s"] = t.L / t.M
    unit[names == "R"] = t.R0
    forced = names != "mu"  # (a multiplier's row is a volume, not a force)
    size = float(np.max(np.abs(K.diagonal()[forced]) * unit[forced]))
    unbalanced = float(np.max(np.abs(force[forced]))) / size if size > 0 else 0.0
    return {"M": M.tocsr(), "K": K, "inertial": inertial, "algebraic": algebraic, "names": names, "force": force,
            "unbalanced": unbalanced}


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


def coupled_modes(model, count=20, vectors=False):
    """The ``count`` lowest modes of the coupled tube linearised about its initial state at rest.

    Returns ``[{"frequency": rad/s, "growth_rate": 1/s}, ...]`` in the order of ``varint.analysis.modes``
    (instabilities first, then frequencies increasing); with ``vectors`` also the mode shapes (nz, count)
    in the model's step unknowns z (algebraic entries: the condensed multipliers / radii).  Raises
    :class:`varint.errors.SolverError` (one line) for states it does not linearise about.
    """
    return modes_of_linearization(model, coupled_linearization(model), count, vectors)


def modes_of_linearization(model, lin, count=20, vectors=False):
    """:func:`coupled_modes` of a :func:`coupled_linearization` already built (``varint modes`` also reads
    its ``unbalanced``)."""
    from .analysis import _modes_from_w2

    Kr, Mr, back = _reduce(lin)
    if Kr.shape[0] > DENSE_COUPLED_LIMIT:
        raise SolverError(f"modes: the coupled tube has {Kr.shape[0]} moving unknowns; the dense eigen-solver is "
                          f"limited to {DENSE_COUPLED_LIMIT} (use fewer nodes or parcels)")
    if Kr.shape[0] == 0:
        return ([], np.zeros((model.nz, 0))) if vectors else []
    w2, X = sla.eigh(Kr, Mr)
    # the threshold of varint.analysis.modes_of: negative w^2 below 1e-14 of the largest |w^2| is round-off
    res = _modes_from_w2(w2[:count], 1e-14 * max(abs(w2[-1]), abs(w2[0]), 1e-300))
    if vectors:
        return res, back(X[:, :count])
    return res


def frequencies(res):
    """The frequencies of a modes list (growing modes give 0), as an array: a convenience for tests and scripts."""
    return np.array([m["frequency"] for m in res])

