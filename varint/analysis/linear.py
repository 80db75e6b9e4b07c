"""Linear analysis: normal modes of the discrete model, and the eigensolvers every model's modes use.

:func:`modes` linearises the *discrete* Lagrangian of the straight tube about a configuration: the
stiffness is the Hessian of the potential in the unknowns, the mass the
lumped diagonal M; algebraic unknowns (quasistatic wall, pressure multipliers)
are condensed statically.  The continuum relation it is compared with (docs/theory.md §6) is
:func:`varint.exact.waves.dispersion_branches`, independent of the lattice.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from ..errors import VarintError

__all__ = ["linearization", "modes", "modes_of", "gyroscopic_modes_of", "sparse_modes_of", "sparse_gyroscopic_modes_of",
           "highest_frequency_estimate"]


def _tube(model):
    """The tube part of a model (its s, R, mu blocks); a part is accepted as it is."""
    return model.tube if hasattr(model, "tube") else model


def linearization(model, z=None, basis=False):
    """Mass (nq,) and condensed stiffness (nq, nq) of the tube's blocks, dense, about z (default: the
    initial state).

    The algebraic unknowns y (a quasistatic wall's radii, a liquid's multipliers) satisfy K_lq x + K_ll y = 0.  Those
    with their own stiffness (the radii) are condensed statically.  A liquid's multipliers have K_bb = 0 (the
    constraint is linear in them); after the radii's condensation they see each other through the wall's compliance,
    K_bb = -K_ba K_aa^-1 K_ab.  With its eigen-split K_bb = U_r S U_r^T + U_0 0 U_0^T, the range part is condensed too
    and the null part leaves constraints on the inertial unknowns, U_0^T K_bq x = 0, whose multipliers do no work on
    admissible motion: x = Z w, Z an orthonormal basis of their null space, and
    Z^T (K_qq - K_qa K_aa^-1 K_aq - K_qb U_r S^-1 U_r^T K_bq) Z w = w^2 Z^T M Z w (docs/theory.md §13.10).  With
    ``basis`` the function returns (M, K, Z): Z None without such constraints (M the diagonal mass, K the condensed
    stiffness), else the reduced dense mass Z^T diag(M) Z and stiffness on the basis Z.  (Before, K_ll was inverted
    whole: a LinAlgError for every liquid in a dynamic wall, where K_ll = 0.)"""
    model = _tube(model)
    if z is None:
        z = np.concatenate([model.q_init, model.lam_init])
    H = model.hessian(model.config(z))
    K = (model.B.T @ H @ model.B).toarray() if sp.issparse(H) else model.B.T @ H @ model.B
    nq = model.nq
    Kqq = K[:nq, :nq]
    Z = None
    if model.nlam:
        K = 0.5 * (K + K.T)
        lam = np.arange(nq, K.shape[0])
        diag = np.abs(np.diag(K))[lam]
        # the algebraic unknowns with their own stiffness (a quasistatic wall's radii) first: condensed statically
        a = lam[diag > 1e-14 * max(float(np.max(diag)) if diag.size else 0.0, 1e-300)]
        b = np.setdiff1d(lam, a)  # the multipliers: K_bb = 0, the constraint is linear in them
        keep = np.r_[np.arange(nq), b]
        if len(a):
            K = K[np.ix_(keep, keep)] - K[np.ix_(keep, a)] @ np.linalg.solve(K[np.ix_(a, a)], K[np.ix_(a, keep)])
        else:
            K = K[np.ix_(keep, keep)]
        Kqq = K[:nq, :nq]
        if len(b):
            Kqb, Kbb = K[:nq, nq:], 0.5 * (K[nq:, nq:] + K[nq:, nq:].T)
            # through a compliant wall the multipliers see each other; the null space of K_bb holds the constraints
            # that stay constraints on the inertial unknowns
            big = float(np.max(np.abs(Kbb))) if Kbb.size else 0.0
            S, U = (np.linalg.eigh(Kbb) if big > 0.0 else (np.zeros(len(b)), np.eye(len(b))))
            rank = np.abs(S) > 1e-10 * max(big, 1e-300)
            if np.any(rank):
                Ur = U[:, rank]
                Kqq = Kqq - (Kqb @ Ur) @ ((Ur.T @ Kqb.T) / S[rank][:, None])
            if not np.all(rank):
                C = U[:, ~rank].T @ Kqb.T  # the constraints on the inertial unknowns
                Z = sla.null_space(C, rcond=1e-10)
    Kqq = 0.5 * (Kqq + Kqq.T)
    if not basis:
        if Z is not None:
            raise VarintError("modes: this model's algebraic unknowns constrain its inertial ones; use linearization(..., "
                              "basis=True)")
        return model.mass.copy(), Kqq
    if Z is None:
        return model.mass.copy(), Kqq, None
    Kr = Z.T @ Kqq @ Z
    return Z.T @ (model.mass[:, None] * Z), 0.5 * (Kr + Kr.T), Z


#: above this many inertial unknowns the tube's modes come from a sparse shift-invert solver
DENSE_TUBE_MODES_LIMIT = 3000


def modes(model, count=20, z=None, vectors=False, method="auto"):
    """Lowest eigenfrequencies of the linearised model.

    Returns a list of ``{"frequency": omega [rad/s], "growth_rate": sigma [1/s]}``
    sorted by frequency (an unstable mode has frequency 0 and sigma > 0);
    with ``vectors`` the mode shapes (nq, count) are returned too.  ``method``: "dense", "sparse"
    (shift-invert Lanczos for the lowest ``count``; models without algebraic unknowns) or "auto"
    (sparse above :data:`DENSE_TUBE_MODES_LIMIT` inertial unknowns when possible).  Rods: see
    :func:`varint.analysis.rod_modes.rod_modes`.
    """
    model = _tube(model)
    sparse = method == "sparse" or (method == "auto" and model.nq > DENSE_TUBE_MODES_LIMIT)
    if sparse and model.nlam:
        if model.nq > 6000:
            raise VarintError("modes: with algebraic unknowns (quasistatic wall or incompressible fluid) the modes "
                              "use the dense eigen-solver, limited to 6000 inertial unknowns")
        sparse = False
    if sparse:
        if z is None:
            z = np.concatenate([model.q_init, model.lam_init])
        H = sp.csr_matrix(model.hessian(model.config(z)))
        K = (model.B.T @ H @ model.B).tocsc()
        return sparse_modes_of(0.5 * (K + K.T), model.mass.copy(), count, vectors)
    M, K, Z = linearization(model, z, basis=True)
    if Z is None:
        return modes_of(K, M, count, vectors)
    if Z.shape[1] == 0:
        raise VarintError("modes: the model has no motion left: its constraints fix every inertial unknown (e.g. a "
                          "liquid in a rigid tube between a velocity inlet and fixed volumes)")
    w2, X = sla.eigh(K, M)
    res = _modes_from_w2(w2[:count], 1e-14 * max(abs(w2[-1]), abs(w2[0]), 1e-300))
    return (res, (Z @ X)[:, :count]) if vectors else res


def modes_of(K, M, count, vectors=False):
    """Generalised eigenproblem K x = w^2 diag(M) x -> modes list (and shapes), in eigenvalue order.

    A negative eigenvalue is an instability (frequency 0, growth rate sqrt(-w^2)) unless it is
    round-off small: below 1e-14 of the largest |w^2| (rigid-body modes of a free rod sit at
    ~1e-17 of it, the eigen-solver's round-off: the same with the exact element Hessian as with the
    finite differences of 0.1; a column at 1.1 x its Euler load at ~2e-13).  Eigenvalue order lists instabilities first, then frequencies increasing.
    """
    w2, X = sla.eigh(K, np.diag(M))
    res = _modes_from_w2(w2[:count], 1e-14 * max(abs(w2[-1]), abs(w2[0]), 1e-300))
    return (res, X[:, :count]) if vectors else res


def _modes_from_w2(w2, floor):
    """w^2 -> {"frequency", "growth_rate"}: a negative w^2 beyond the round-off ``floor`` is a growth rate."""
    return [{"frequency": math.sqrt(max(lam, 0.0)), "growth_rate": 0.0} if lam >= -floor
            else {"frequency": 0.0, "growth_rate": math.sqrt(-lam)} for lam in w2]


def _arpack(solver, *args, **kw):
    """Call a scipy ARPACK solver; its failures become one-line errors."""
    import scipy.sparse.linalg as spla

    try:
        return solver(*args, **kw)
    except (spla.ArpackNoConvergence, RuntimeError) as exc:
        raise VarintError(f"modes: the sparse eigen-solver (ARPACK) failed ({str(exc).splitlines()[0]}); "
                          "ask for fewer modes (-n)") from None


def gyroscopic_modes_of(K, G, M, count, vectors=False):
    """Modes of M q'' + G q' + K q = 0 (G skew: gyroscopic; diag(M)) -> modes list (and shapes).

    The first-order form x' = A x, x = (q, q'), has a Hamiltonian spectrum: eigenvalues come as
    +-lam (and conjugates).  Each degree of freedom is reported once: an oscillation +-i w as
    frequency w; a real pair +-s as frequency 0, growth rate s; a flutter quadruple +-a +- i w as two
    entries (w, |a|).  Zero eigenvalues (rigid motions, Jordan blocks) are those below 1e-7 of the
    largest |lam|: their round-off splitting is ~sqrt(eps); for the same reason real and imaginary
    parts below that are reported as 0 (the threshold of :func:`modes_of`, 1e-14 on w^2).  Sorted
    by frequency, then growth rate descending; with ``vectors`` the complex displacement parts of
    the mode shapes too.
    """
    n = len(M)
    A = np.zeros((2 * n, 2 * n))
    A[:n, n:] = np.eye(n)
    A[n:, :n] = -K / M[:, None]
    A[n:, n:] = -G / M[:, None]
    lam, X = sla.eig(A)
    return _one_per_degree_of_freedom(lam, X[:n], 1e-7 * max(np.max(np.abs(lam)), 1e-300), count, vectors, complete=True)


def _one_per_degree_of_freedom(lam, X, tiny, count, vectors, complete):
    """Select one eigenvalue per degree of freedom from a Hamiltonian spectrum (see above).

    ``complete``: ``lam`` is the whole spectrum, so half of a cluster of zeros is one per degree of
    freedom; otherwise (a partial, shift-inverted spectrum) every zero found is kept and paired by
    the order it comes in.  ``tiny``: magnitudes (and real or imaginary parts) below it are round-off.
    """
    zero = np.abs(lam) <= tiny
    keep = ~zero & ((lam.imag > tiny) | ((np.abs(lam.imag) <= tiny) & (lam.real > 0)))
    zeros = np.flatnonzero(zero)
    picks = list(np.flatnonzero(keep)) + list(zeros[: (len(zeros) + (0 if complete else 1)) // 2])
    res = []
    for i in picks:
        real_pair = abs(lam[i].imag) <= tiny and not zero[i]
        res.append({"frequency": 0.0 if zero[i] or real_pair else float(lam[i].imag),
                    "growth_rate": 0.0 if zero[i] or abs(lam[i].real) <= tiny else float(abs(lam[i].real))})
    order = sorted(range(len(res)), key=lambda k: (res[k]["frequency"], -res[k]["growth_rate"]))
    res = [res[k] for k in order][:count]
    if vectors:
        return res, X[:, [picks[k] for k in order][:count]]
    return res


def highest_frequency_estimate(K, M):
    """max_i sqrt(sum_j |K_ij| / M_i): a Gershgorin bound on the largest frequency (sparse or dense K)."""
    rows = np.asarray(abs(K).sum(axis=1)).ravel()
    return float(np.sqrt(np.max(rows / M)))


#: shifts of the shift-invert Lanczos solver, -shift x (Gershgorin bound on w^2), tried in turn: just
#: below zero, so that rigid modes (K singular) are found with the lowest oscillations.  1e-8 keeps
#: ARPACK accurate beside rigid modes (at 1e-14 their huge inverted eigenvalues cost a free rod's
#: elastic pair 2e-4); a slender rod's lowest w^2 is ~1e-15 of the bound at L/r = 10^4, where 1e-8
#: does not converge and 1e-14 does (the rigid modes' round-off, ~1e-19 of the bound, stays below it).
SPARSE_SHIFTS = (1e-8, 1e-14)


def sparse_modes_of(K, M, count, vectors=False):
    """The lowest ``count`` modes of K x = w^2 diag(M) x by shift-invert Lanczos (scipy eigsh).

    For models too large for the dense solver.  The shift sits just below zero (:data:`SPARSE_SHIFTS` of
    the largest w^2, estimated by :func:`highest_frequency_estimate`), so rigid modes and instabilities are found
    with the lowest oscillations; classification as in :func:`modes_of`.
    """
    import scipy.sparse.linalg as spla

    K = sp.csc_matrix(K)
    big2 = highest_frequency_estimate(K, M) ** 2  # a bound, often well above the true highest w^2
    k = min(count, K.shape[0] - 2)
    # a fixed start vector: ARPACK's default is random, and results must not change between runs
    for i, shift in enumerate(SPARSE_SHIFTS):
        try:
            # (shift-invert converges in tens of restarts when it converges: the first shift gets 300)
            w2, X = _arpack(spla.eigsh, K, k=k, M=sp.diags(M).tocsc(), sigma=-shift * big2, which="LM",
                            v0=np.ones(K.shape[0]), maxiter=300 if i < len(SPARSE_SHIFTS) - 1 else None)
            break
        except VarintError:
            if i == len(SPARSE_SHIFTS) - 1:
                raise
    order = np.argsort(w2)
    w2, X = w2[order], X[:, order]
    # eigenvalues near the shift come out with small absolute error: a threshold of 1e-9 of the
    # bound on the frequency (1e-18 on w^2), where the dense solver needs 1e-7
    res = _modes_from_w2(w2, 1e-18 * big2)
    return (res, X) if vectors else res


def sparse_gyroscopic_modes_of(K, G, M, count, vectors=False):
    """The lowest ``count`` modes of M q'' + G q' + K q = 0 by shift-invert Arnoldi (scipy eigs) on the
    first-order form, shifted by 1e-4 of the estimated highest frequency; classification as in
    :func:`gyroscopic_modes_of` with round-off below 1e-9 of that (Gershgorin, so generous) estimate.
    For models too large for the dense solver."""
    import scipy.sparse.linalg as spla

    n = len(M)
    Minv = sp.diags(1.0 / M)
    A = sp.bmat([[None, sp.identity(n)], [-(Minv @ sp.csr_matrix(K)), -(Minv @ sp.csr_matrix(G))]]).tocsc()
    big = highest_frequency_estimate(K, M)
    k = min(2 * count + 4, 2 * n - 2)
    lam, X = _arpack(spla.eigs, A, k=k, sigma=1e-4 * big, which="LM", v0=np.ones(2 * n))
    return _one_per_degree_of_freedom(lam, X[:n], 1e-9 * big, count, vectors, complete=False)


# ---------------------------------------------------------------------------
# classical beam results, solved independently of the lattice (for validation)


