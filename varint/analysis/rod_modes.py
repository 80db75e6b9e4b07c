"""Linear modes of the rod (docs/theory.md §9): the space-discrete Lagrangian linearised about a configuration.

Stiffness from the exact element Hessians of the discrete potential (:func:`varint.model.statics.force_jacobian`),
lumped mass, and about a steady rotation the gyroscopic matrix and centrifugal stiffness of
:func:`varint.model.statics.rotating_frame_kinetics`.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from ..errors import SolverError
from ..model.statics import (check_rotating_base, force_jacobian, lumped_mass, potential_gradient, refuse_constrained,
                             rod_part, rotating_frame_kinetics)
from ..terms.rod_constraint import constraint_static
from .linear import gyroscopic_modes_of, modes_of, sparse_gyroscopic_modes_of, sparse_modes_of

__all__ = ["rod_modes", "DENSE_MODES_LIMIT", "DENSE_SPREAD_LIMIT"]


#: above this many unknowns rod_modes uses the sparse shift-invert solvers (dense eig is O(n^3))
DENSE_MODES_LIMIT = 1500


#: ... and above this bound on eps x (Gershgorin bound of the largest w^2 / the bending scale
#: EI / (rho A L^4)): a dense solver's round-off is relative to the largest w^2 and reaches the lowest
#: frequencies of a slender rod.  Measured: a solid cantilever of L/r = 10^4 at 100 elements (bound
#: 6.3e3) read its first two bending w 1e-2 and 4e-3 off with the dense solver (~1e-6 x the bound), 2.5e-5 (the lattice
#: error) with the sparse one; at the limit 1 (L/r ~ 1100) the dense error is ~1e-6.  The examples and
#: the PyElastica section (L/r = 100, bound 6e-5) stay dense.
DENSE_SPREAD_LIMIT = 1.0


def _spectral_spread(model, K, M):
    """eps times a Gershgorin bound on the largest w^2 over the bending scale EI / (rho A L^4)."""
    model = rod_part(model)
    sec = model.section
    bending = sec.EI / (sec.rhoA * model.L ** 4)
    top = float(np.max(np.asarray(abs(K).sum(axis=1)).ravel() / M))
    return np.finfo(float).eps * top / bending


def rod_modes(model, count=20, vectors=False, Lam=None, r=None, Omega=None, method="auto", lam=None):
    """Eigenfrequencies of the rod linearised about a configuration (default: the initial state).

    Stiffness: the Hessian of the discrete potential in (dr, sigma) (exact element Hessians,
    :func:`force_jacobian`); mass: the lumped diagonal of the kinetic energy.  With ``Omega`` (default: the
    scene's initial angular velocity) the linearisation is about a steady rotation, in the frame
    spinning with it: the gyroscopic matrix G = C - C^T and the centrifugal stiffness -H of
    :func:`rotating_frame_kinetics` enter, and the state must be a relative equilibrium there.
    ``method``: "dense" (every mode), "sparse" (the lowest ``count``, shift-invert) or "auto"
    (sparse above :data:`DENSE_MODES_LIMIT` unknowns, or for a rod so slender that the dense solver's
    round-off would reach the lowest frequencies: :data:`DENSE_SPREAD_LIMIT`).
    Returns ``[{"frequency": rad/s, "growth_rate": 1/s}, ...]`` sorted by frequency.
    """
    model = rod_part(model)
    if model.constrained:
        return _constrained_modes(model, count, vectors, Lam, r, Omega, lam)
    mask = model.mask
    Lam = model.Lam0 if Lam is None else Lam
    r = model.r0 if r is None else r
    if Omega is None:
        Omega = model.spin
    # refusals first: they need no stiffness matrix
    if not model.free and np.any(model.velocity):
        raise SolverError("modes: a rod with a pinned or clamped end has no steady translation: "
                          "rod.initial.velocity must be zero")
    if np.any(Omega):
        check_rotating_base(model, Omega)
    K = -force_jacobian(model, Lam, r)
    K = (0.5 * (K + K.T)).tocsc()
    M = lumped_mass(model)[mask]
    # (the spread rule is for the symmetric problem only: the gyroscopic sparse path orders the modes
    # of a spinning rod's rigid and near-rigid motions differently, and is not chosen by it)
    sparse = method == "sparse" or (method == "auto" and (
        model.nz > DENSE_MODES_LIMIT
        # (and only where the sparse solver can return every mode asked for: it gives at most nz - 2)
        or (not np.any(Omega) and model.nz > count + 2 and _spectral_spread(model, K, M) > DENSE_SPREAD_LIMIT)))
    if not np.any(Omega):
        return sparse_modes_of(K, M, count, vectors) if sparse else modes_of(K.toarray(), M, count, vectors)
    b, C, H = rotating_frame_kinetics(model, Omega, Lam, r)
    f = potential_gradient(model, Lam, r) + b
    # force scale: the centrifugal loads, or the elastic force of a unit strain (diag K x unit displacement)
    unit = np.where(np.flatnonzero(mask.ravel()) % 6 < 3, model.ds, 1.0)
    size = max(np.max(np.abs(b)), np.max(np.abs(K.diagonal()) * unit))
    unbalanced = np.max(np.abs(f[mask]))
    if unbalanced > 1e-9 * size:
        raise SolverError(f"modes: the state is not a steady rotation at angular_velocity {list(map(float, Omega))}: "
                          f"unbalanced generalised force {unbalanced:.3g} (centrifugal {np.max(np.abs(b)):.3g}); "
                          "--about static linearises about its steady rotation instead")
    idx = np.flatnonzero(mask.ravel())
    Cf = sp.block_diag(list(C)).tocsr()[idx][:, idx]
    Hf = sp.block_diag(list(H)).tocsr()[idx][:, idx]
    if sparse:
        return sparse_gyroscopic_modes_of(K - Hf, Cf - Cf.T, M, count, vectors)
    return gyroscopic_modes_of((K - Hf).toarray(), (Cf - Cf.T).toarray(), M, count, vectors)


def _constrained_modes(model, count, vectors, Lam, r, Omega, lam):
    """Modes of the inextensible, unshearable rod (docs/theory.md §9a): the stiffness with the geometric
    stiffness of the element forces ``lam`` (from :func:`static_equilibrium`'s ``info["element_forces"]``;
    zero about an unloaded state), restricted to the null space of the constraint's Jacobian G, against the
    lumped mass there (dense)."""
    Lam = model.Lam0 if Lam is None else Lam
    r = model.r0 if r is None else r
    if np.any(model.spin if Omega is None else Omega):
        refuse_constrained(model, "modes about a steady rotation")
    lam = np.zeros((model.N, 3)) if lam is None else lam
    _, G, _, Hc = constraint_static(model, Lam, r, lam)
    K = -(force_jacobian(model, Lam, r) + Hc).toarray()
    K = 0.5 * (K + K.T)
    Z = sla.null_space(G.toarray())
    Mz = Z.T @ (lumped_mass(model)[model.mask][:, None] * Z)
    w2, Y = sla.eigh(Z.T @ K @ Z, Mz)
    order = np.argsort(w2)[:count]
    out = []
    for w in w2[order]:
        out.append({"frequency": float(np.sqrt(w)) if w > 0 else 0.0, "growth_rate": float(np.sqrt(-w)) if w < 0 else 0.0})
    if vectors:
        return out, Z @ Y[:, order]
    return out
