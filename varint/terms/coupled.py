"""Terms of the coupled tube's discrete Lagrangian as label-local kernels (docs/theory.md §10.4–10.5).

The fluid's kinetic energy in inertial form (§10.4): over one step n -> n+1,

    L_kin = h sum_k 1/2 mbar_k |X_k^{n+1} - X_k^n|^2 / h^2,     X_k^l = X(s_k^l; r^l),

with X the Catmull–Rom centreline of :mod:`varint.lattice.centreline` and mbar_k the label masses
(mean of the two adjacent parcels; the end labels move with the rod's end nodes). Each label's
contribution reads only its own label at both levels and the four nodes of its element at each level,
so it is an element-local kernel: :func:`fluid_kinetic_step` returns, per label, the values of its
26 local unknowns' indices (s^n, r^n of 4 nodes, s^{n+1}, r^{n+1} of 4 nodes), the gradient and the
Hessian in them, exactly (X is linear in r and cubic in s).  The assembly (the one model of
docs/theory.md §10) takes D1 = d/d(level n), D2 = d/d(level n+1) and the Newton block d D1/d(level n+1)
from these.

Because the weights sum to one, L_kin is unchanged when r at both levels is moved by one rigid motion:
the discrete linear and angular momenta of the fluid are its Noether momenta (tested).

The fluid's potential part of the midpoint L_d (§10.4.2), as a function of both levels,

    L_pot = -h [ sum_k m_k e(m_k/Vbar_k, S_k)   (or -sum_k mu_k (Vbar_k - V0_k), incompressible)
                 + p_ext Vol(Rbar, gamma) - g . sum_k mbar_k X(sbar_k; rbar) ],

with Vbar_k the stretched parcel volumes of §10.3 at the midpoint data (sbar, Rbar and the nodal stretch
gamma of the strain midpoint |Gammabar_e|), is :func:`fluid_potential_step`.  It returns the level
gradients D1, D2 in the stepper's layout (rod [dr, sigma] per node, labels, radii) and D_mu, and on request
the Newton block: the exact derivative of D1 (translational rod rows rotated into the level-n body frame)
and D_mu with respect to the step unknowns (b, xi; s^{n+1}; R^{n+1}; mu).  :func:`fluid_kinetic_chart`
gives the same for :func:`fluid_kinetic_step`, so both assemble the same way.

How the exact derivatives are organised.  The fluid reaches the rod only through the element stretches
G_e = |Gammabar_e| (and gravity through X): with y = (sbar, Rbar, gamma, mu) the potential is
U(y) - g . sum mbar X, the nodal stretch is linear, gamma = T G, and

    dL/dGammabar_e = -h (T^T dU/dgamma)_e ghat_e,      ghat_e = Gammabar_e / G_e,
    D_l rod = 1/2 A^lT dL/dGammabar,                  A^l: the Lie-variation Jacobian of Gamma^l (§10.3),

A^l being the rod's strain Jacobian of varint/terms/rod.py (`k_element`: dGamma/ddr_a = -(La + Lb)^T/(2 ds),
dGamma/dsigma_a = hat(p_a)/(2 ds)).  The Newton block is the chain rule of this through the exact
Hessian of U in y (per-parcel Hessians of varint/lattice/centreline.py `stretched_volume_derivatives`,
the closed-form Hessian of Vol) and the exact first derivatives of Gamma^{n+1} in the chart
r^{n+1} = r^n + Lambda^n b, Lambda^{n+1} = Lambda^n cay(xi) (a xi-variation is the body variation
sigma = dcay_{-xi} dxi, varint/lattice/lie.py).  A^n does not depend on the unknowns, so no second derivative of
the strains is needed.  Each piece is element- or parcel-local; they are chained as sparse matrices
whose pattern is the stencil of §10.5 (parcel k: labels k, k+1, radii of nodes e0..e1+1, r and Lambda of
nodes e0-1..e1+2; gravity: label k and its 4 centreline nodes).

Two implementations of the same algebra.  The default (``fast=True``) is compiled (numba): the gradient in
two kernels around the equation of state, the Newton block in one that builds the y-space Hessian, the
column map dy/du and the row map of D1 and D_mu as short CSR lists and multiplies them out row by row
(Gustavson's product with a marker array), so each entry of the block comes out once; the kinetic chart
in one label loop.  The NumPy/scipy path (``fast=False``: the sparse chain above, matrix by matrix) is
kept as the reference the tests compare the kernels with (tests/test_coupled_terms.py); labels the
kernels cannot read (not finite, out of order, off a closed centreline) go to it, so both raise the same
errors.  Timings: scripts/bench_coupled_terms.py.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp

from ..lattice.centreline import (centreline_and_weights, k_stretch_weight, k_whole_element, nodal_stretch,
                                  stretched_volume_derivatives, stretched_volumes)
from ..lattice.lie import cay_inv, dcay, hat
from .rod import level_strains

__all__ = ["fluid_kinetic_step", "LOCAL_SIZE", "FluidPotential", "LevelGradient", "StepTerm", "fluid_potential_step",
           "fluid_kinetic_chart", "newton_offsets", "stretch_map", "element_strains", "fluid_potential_static",
           "fluid_kinetic_metric", "stretched_volumes_of", "label_velocity_map", "kinetic_metric_of"]

#: local unknowns of one label's kinetic contribution: s^n, r^n (4 nodes x 3), s^{n+1}, r^{n+1} (4 x 3)
LOCAL_SIZE = 26


def fluid_kinetic_step(s0, r0, s1, r1, mbar, h, ds, periodic=False, period=None, hessian=True):
    """One step's fluid kinetic action, with exact label-local gradients and Hessians.

    Parameters
    ----------
    s0, s1 : (M+1,) labels at levels n and n+1
    r0, r1 : (n_nodes, 3) nodal positions at levels n and n+1
    mbar : (M+1,) label masses
    period : (3,) shift vector d with r_{j+N} = r_j + d (periodic tubes; default L e_1)

    Returns
    -------
    L : float
        h sum_k 1/2 mbar_k |dX_k|^2 / h^2.
    index : (M+1, 26) int
        Global indices of each label's local unknowns in the layout
        ``[s^n (M+1) | r^n (3 n_nodes, node-major) | s^{n+1} (M+1) | r^{n+1} (3 n_nodes)]``.
    grad : (M+1, 26), hess : (M+1, 26, 26)
        Gradient and Hessian of the label's contribution in its local unknowns (an index may occur twice
        where a closed end folds a ghost node onto a real one: sum the entries); ``hess`` is None when
        ``hessian`` is false (a residual evaluation needs only the gradient).
    """
    s0 = np.asarray(s0, dtype=np.float64)
    s1 = np.asarray(s1, dtype=np.float64)
    r0 = np.asarray(r0, dtype=np.float64)
    r1 = np.asarray(r1, dtype=np.float64)
    mbar = np.asarray(mbar, dtype=np.float64)
    n_nodes, n_lab = len(r0), len(s0)
    nodes0, N0, dN0, X0, dX0, d2X0 = centreline_and_weights(s0, r0, ds, periodic, period)
    nodes1, N1, dN1, X1, dX1, d2X1 = centreline_and_weights(s1, r1, ds, periodic, period)
    D = X1 - X0
    c = mbar / h
    L = float(0.5 * np.sum(c * np.sum(D * D, axis=1)))

    # local layout: 0 s^n | 1..12 r^n (node a, component d at 1 + 3a + d) | 13 s^{n+1} | 14..25 r^{n+1}
    index = np.empty((n_lab, LOCAL_SIZE), np.int64)
    k = np.arange(n_lab)
    comp = np.arange(3)
    index[:, 0] = k
    index[:, 13] = n_lab + 3 * n_nodes + k
    index[:, 1:13] = (n_lab + 3 * nodes0[:, :, None] + comp[None, None, :]).reshape(n_lab, 12)
    index[:, 14:26] = (2 * n_lab + 3 * n_nodes + 3 * nodes1[:, :, None] + comp[None, None, :]).reshape(n_lab, 12)

    # Jacobian of D = X1 - X0 in the local unknowns: (M+1, 3, 26)
    JD = np.zeros((n_lab, 3, LOCAL_SIZE))
    JD[:, :, 0] = -dX0
    JD[:, :, 13] = dX1
    eye = np.eye(3)
    JD[:, :, 1:13] = -(N0[:, None, :, None] * eye[None, :, None, :]).reshape(n_lab, 3, 12)
    JD[:, :, 14:26] = (N1[:, None, :, None] * eye[None, :, None, :]).reshape(n_lab, 3, 12)
    grad = c[:, None] * np.einsum("kc,kcv->kv", D, JD)
    if not hessian:
        return L, index, grad, None

    # Hessian: c (JD^T JD + sum_c D_c d2 D_c); X is linear in r, so d2 D_c lives on (s, s) and (s, r) only
    hess = c[:, None, None] * (np.swapaxes(JD, 1, 2) @ JD)
    hess[:, 13, 13] += c * np.sum(D * d2X1, axis=1)
    hess[:, 0, 0] -= c * np.sum(D * d2X0, axis=1)
    # d2 X / ds dr_{a,d} = N'_a e_d: the (s, r) entries are c D_d N'_a
    mixed1 = c[:, None, None] * dN1[:, :, None] * D[:, None, :]   # (M+1, 4, 3)
    mixed0 = -c[:, None, None] * dN0[:, :, None] * D[:, None, :]
    hess[:, 13, 14:26] += mixed1.reshape(n_lab, 12)
    hess[:, 14:26, 13] += mixed1.reshape(n_lab, 12)
    hess[:, 0, 1:13] += mixed0.reshape(n_lab, 12)
    hess[:, 1:13, 0] += mixed0.reshape(n_lab, 12)
    return L, index, grad, hess


# ---------------------------------------------------------------------------
# step gradients and Newton blocks in the stepper's layout (docs/theory.md §10.5)
#
# Layout of a level's gradient: rod (n_nodes, 6) = [d/d(dr) spatial | d/d(sigma) body] per node, the
# variation of a frame being Lambda -> Lambda cay(sigma); labels (M+1,); radii (nR,); and, for the
# incompressible fluid, D_mu (M,) of the half level.  Every label and every node is an entry of its own:
# fixed end labels, the periodic identification s_M = s_0 + L and supports are the assembly's business
# (as B in varint/model/model.py).
#
# Newton ordering (rows and columns): [rod: 6 per node, node-major | s: M+1 | R: nR | mu: M].  Rows are
# D1 (level-n variations) with each node's translational rows rotated into its level-n body frame
# (Lambda_j^nT D1_{r_j}), then D_mu; columns are the step unknowns u of docs/theory.md §10.1: per node
# b_j = Lambda_j^nT (r_j^{n+1} - r_j^n) and xi_j = cay^-1(Lambda_j^nT Lambda_j^{n+1}), then s^{n+1},
# R^{n+1}, mu — exactly the convention of varint/terms/rod.py `_k_step_blocks`.


class LevelGradient(NamedTuple):
    """Derivatives of a step term with respect to the variations of one time level."""

    rod: np.ndarray   # (n_nodes, 6): [dr (spatial, 3), sigma (body, 3)]
    s: np.ndarray     # (M+1,)
    R: np.ndarray     # (nR,)


class StepTerm(NamedTuple):
    """A step term's value L, its level gradients D1 (level n), D2 (level n+1), the half-level D_mu
    (None unless incompressible) and, when asked for, its Newton block as COO (rows, cols, vals)."""

    L: float
    D1: LevelGradient
    D2: LevelGradient
    Dmu: np.ndarray | None
    newton: tuple | None


def level_chart_maps(Lam_n, xi, n_rest):
    """(Rot, Chart): sparse maps between a level gradient's rod entries per node [dr spatial, sigma] and the step's
    Newton rows and columns (docs/theory.md §10.9): Rot turns each node's translational rows into its level-n body
    frame (Lambda_n^T), Chart chains columns through dr = Lambda_n db, sigma = dcay_{-xi} dxi; the ``n_rest`` entries
    after the nodes' (labels, radii) pass unchanged."""
    k = len(Lam_n)
    blk_rot = np.zeros((k, 6, 6))
    blk_rot[:, :3, :3] = np.swapaxes(Lam_n, 1, 2)
    blk_rot[:, 3:, 3:] = np.eye(3)
    blk_chart = np.zeros((k, 6, 6))
    blk_chart[:, :3, :3] = Lam_n
    blk_chart[:, 3:, 3:] = dcay(-xi)
    eye = sp.identity(n_rest, format="csr")
    Rot = sp.block_diag([sp.block_diag(list(blk_rot), format="csr"), eye], format="csr")
    Chart = sp.block_diag([sp.block_diag(list(blk_chart), format="csr"), eye], format="csr")
    return Rot, Chart


def newton_offsets(n_nodes, n_labels, nR, n_mu=0):
    """Offsets of the blocks in the Newton ordering, and its size: ``({"rod", "s", "R", "mu"}, n)``."""
    off = {"rod": 0, "s": 6 * n_nodes, "R": 6 * n_nodes + n_labels, "mu": 6 * n_nodes + n_labels + nR}
    return off, off["mu"] + n_mu


@dataclass(frozen=True)
class FluidPotential:
    """Constant data of the fluid's potential term on the coupled tube (docs/theory.md §10.4.2).

    ``eos`` is an equation of state in the form of varint/terms/thermo.py (``psi(V, m, S)`` the parcel internal
    energy m e(m/V, S), ``dpsi(V, m, S)`` its first and second V-derivatives, -p and -dp/dV); ``eos=None``
    means incompressible, with reference volumes ``V0`` and multipliers mu.  ``mbar`` (M+1,) are the label
    masses of §10.1 (closed ends included: mbar_0 = m_0/2, mbar_M = m_{M-1}/2; periodic: label M is
    label 0 shifted by the period, so mbar_0 = (m_{M-1} + m_0)/2 and mbar_M = 0 — counted once, as
    varint/terms/tube.py does), ``g`` the gravity vector, ``period`` the shift d of a periodic tube (default
    L e_1).
    """

    ds: float
    m: np.ndarray
    mbar: np.ndarray
    eos: object = None
    S: np.ndarray | None = None
    V0: np.ndarray | None = None
    p_ext: float = 0.0
    g: np.ndarray = field(default_factory=lambda: np.zeros(3))
    periodic: bool = False
    period: np.ndarray | None = None

    @property
    def incompressible(self):
        return self.eos is None


# -- lattice pieces ------------------------------------------------------------------------------


def _scatter(idx, vals, n):
    """sum of vals over equal indices into a vector of length n (np.add.at, an order of magnitude faster)."""
    return np.bincount(np.ravel(idx), weights=np.ravel(vals), minlength=n)


def _scatter_rows(idx, vals, n):
    """(n, 3) sums of the rows vals (k, 3) over equal row indices idx (k,)."""
    idx = np.ravel(idx)
    flat = (3 * idx[:, None] + np.arange(3)).ravel()
    return _scatter(flat, np.reshape(vals, (-1, 3)), 3 * n).reshape(n, 3)


def _topology(n_nodes, periodic, ds, period):
    """Elements (a, b) and the shift added to r_b - r_a (the period d on a periodic tube's closing element)."""
    n_el = n_nodes if periodic else n_nodes - 1
    ia = np.arange(n_el)
    ib = (ia + 1) % n_nodes
    shift = np.zeros((n_el, 3))
    if periodic:
        d = np.array([n_nodes * ds, 0.0, 0.0]) if period is None else np.asarray(period, dtype=np.float64)
        shift[-1] = d
    return ia, ib, shift


def element_strains(Lam, r, ds, periodic=False, period=None):
    """Gamma_e = (Lambda_a + Lambda_b)^T (r_b - r_a) / (2 ds) of every element (§9, §10.1), with the
    body-frame chords p_a = Lambda_a^T (r_b - r_a), p_b = Lambda_b^T (r_b - r_a): ``(Gamma, p_a, p_b)``
    (varint.terms.rod.level_strains)."""
    st = level_strains(np.asarray(Lam, dtype=np.float64), np.asarray(r, dtype=np.float64), ds, periodic, period)
    return st.Gamma, st.pa, st.pb


@lru_cache(maxsize=16)
def stretch_map(n_nodes, periodic=False):
    """The linear map T (nR x n_el, sparse) with gamma = T G: the nodal stretch of §10.3 (mean of the
    adjacent elements; a closed end node takes its only element's): the entries varint.lattice.centreline.k_stretch_weight
    of the compiled kernels.  Cached: do not modify it."""
    n_el = n_nodes if periodic else n_nodes - 1
    e = np.arange(n_el)
    rows = np.concatenate([e, (e + 1) % n_nodes])
    vals = np.array([k_stretch_weight(int(j), n_nodes, periodic) for j in rows])
    return sp.csr_matrix((vals, (rows, np.concatenate([e, e]))), shape=(n_nodes, n_el))


def stretched_volumes_of(s, R, Gamma, ds, periodic=False):
    """The parcels' stretched volumes (§10.3) at labels s, nodal radii R and element strains Gamma (n_el, 3) (a level's,
    or the strain midpoint of a step): the nodal stretch of |Gamma_e| (varint.lattice.centreline.nodal_stretch) into
    varint.lattice.centreline.stretched_volumes."""
    return stretched_volumes(s, R, nodal_stretch(np.linalg.norm(Gamma, axis=1), periodic), ds, periodic)


def _strain_jacobian(Lsum, pa, pb, ds):
    """A_e (n_el, 3, 12): dGamma_e / d[dr_a (spatial), sigma_a (body), dr_b, sigma_b] at one level.

    Lambda -> Lambda cay(sigma) turns Lambda^T dr into p + p x sigma, so dGamma/dsigma_a = hat(p_a)/(2 ds).
    """
    n_el = pa.shape[0]
    A = np.empty((n_el, 3, 12))
    LT = np.swapaxes(Lsum, 1, 2) / (2.0 * ds)
    A[:, :, 0:3] = -LT
    A[:, :, 3:6] = hat(pa) / (2.0 * ds)
    A[:, :, 6:9] = LT
    A[:, :, 9:12] = hat(pb) / (2.0 * ds)
    return A


def _rod_gradient(gG, Lsum, pa, pb, ia, ib, ds, n_nodes):
    """A^T gG summed over elements into (n_nodes, 6), gG (n_el, 3) = dL/dGamma_e at this level."""
    out = np.empty((n_nodes, 6))
    f = np.einsum("eij,ej->ei", Lsum, gG) / (2.0 * ds)
    both = np.concatenate([ia, ib])
    out[:, :3] = _scatter_rows(both, np.concatenate([-f, f]), n_nodes)
    out[:, 3:] = _scatter_rows(both, np.concatenate([np.cross(gG, pa), np.cross(gG, pb)]) / (2.0 * ds), n_nodes)
    return out


def _potential_in_y(fp, sbar, Rbar, gamma, mu, want_hessian):
    """U_f(y) = internal energy (or the constraint term) + p_ext Vol at y = (sbar, Rbar, gamma, mu).

    Returns (U, grad (ny,), Hessian as COO (rows, cols, vals) or None); y has the layout of
    `stretched_volume_derivatives` extended by mu: [labels 0..M | radii | stretches | mu 0..M-1].
    """
    n_lab, nR = len(sbar), len(Rbar)
    M = n_lab - 1
    o_R, o_g, o_mu = n_lab, n_lab + nR, n_lab + 2 * nR
    ny = o_mu + (M if fp.incompressible else 0)
    V, idx, gV, HV = stretched_volume_derivatives(sbar, Rbar, gamma, fp.ds, fp.periodic)
    idx = np.where(idx >= 0, idx, 0)  # padded slots carry zero derivatives
    grad = np.zeros(ny)
    rows, cols, vals = [], [], []
    if fp.incompressible:
        U = -float(np.dot(mu, V - fp.V0))
        grad += _scatter(idx, -mu[:, None] * gV, ny)
        grad[o_mu:] = -(V - fp.V0)
        if want_hessian:
            n_loc = idx.shape[1]
            rows += [np.broadcast_to(idx[:, :, None], HV.shape).ravel()]
            cols += [np.broadcast_to(idx[:, None, :], HV.shape).ravel()]
            vals += [(-mu[:, None, None] * HV).ravel()]
            kmu = np.broadcast_to((o_mu + np.arange(M))[:, None], (M, n_loc)).ravel()
            rows += [kmu, idx.ravel()]
            cols += [idx.ravel(), kmu]
            vals += [-gV.ravel(), -gV.ravel()]
    else:
        U = float(np.sum(fp.eos.psi(V, fp.m, fp.S)))
        d1, d2 = fp.eos.dpsi(V, fp.m, fp.S)
        grad += _scatter(idx, d1[:, None] * gV, ny)
        if want_hessian:
            rows += [np.broadcast_to(idx[:, :, None], HV.shape).ravel()]
            cols += [np.broadcast_to(idx[:, None, :], HV.shape).ravel()]
            vals += [(d2[:, None, None] * gV[:, :, None] * gV[:, None, :] + d1[:, None, None] * HV).ravel()]
    if fp.p_ext != 0.0:
        # Vol = sum_e ds pi/12 [gamma_a (3a^2 + 2ab + b^2) + gamma_b (a^2 + 2ab + 3b^2)]: G_e(1) of
        # varint/lattice/centreline.py, the whole element (§10.3)
        ia, ib, _ = _topology(nR, fp.periodic, fp.ds, None)
        w = k_whole_element(Rbar[ia], Rbar[ib], gamma[ia], gamma[ib])
        c = fp.p_ext * fp.ds * np.pi / 12.0
        U += float(np.sum(c * w[0]))
        iR_a, iR_b, ig_a, ig_b = o_R + ia, o_R + ib, o_g + ia, o_g + ib
        grad += _scatter(np.concatenate([iR_a, iR_b, ig_a, ig_b]), np.concatenate([c * w[1], c * w[2], c * w[3], c * w[4]]),
                         ny)
        if want_hessian:
            pairs = [(iR_a, iR_a, w[5]), (iR_b, iR_b, w[6]), (iR_a, iR_b, w[7]), (iR_a, ig_a, w[8]), (iR_a, ig_b, w[9]),
                     (iR_b, ig_a, w[10]), (iR_b, ig_b, w[11])]
            for i, j, v in pairs:
                rows += [i] if i is j else [i, j]
                cols += [j] if i is j else [j, i]
                vals += [c * v] if i is j else [c * v, c * v]
    H = None
    if want_hessian:
        H = (np.concatenate(rows).astype(np.int64), np.concatenate(cols).astype(np.int64), np.concatenate(vals))
    return U, grad, H


def fluid_potential_step(fp, h, s0, r0, Lam0, R0, s1, r1, Lam1, R1, mu=None, newton=False, fast=True):
    """The fluid's potential part of one step's L_d (midpoint, §10.4.2) with exact derivatives.

    Parameters
    ----------
    fp : FluidPotential
    h : time step
    s0, s1 : (M+1,) labels; r0, r1 : (n_nodes, 3) positions; Lam0, Lam1 : (n_nodes, 3, 3) frames;
    R0, R1 : (nR,) nodal radii — each at levels n and n+1
    mu : (M,) multipliers of the half level (incompressible only)
    newton : also return the Newton block (see the module's layout notes)

    Returns
    -------
    StepTerm(L, D1, D2, Dmu, newton): D1, D2 are :class:`LevelGradient` of the level-n and level-(n+1)
    variations (r -> r + dr spatial, Lambda -> Lambda cay(sigma), s, R); Dmu = dL/dmu = h (Vbar - V0);
    newton = (rows, cols, vals) in the ordering [rod 6/node | s | R | mu] (duplicates summed).

    ``fast`` (default) runs the compiled kernels (:func:`_potential_fast`); ``fast=False`` the NumPy/scipy
    reference (:func:`_potential_numpy`), which the tests compare them with.  Both give the same numbers to
    round-off, and the same errors for labels off the tube.
    """
    if fast:
        return _potential_fast(fp, h, s0, r0, Lam0, R0, s1, r1, Lam1, R1, mu, newton)
    return _potential_numpy(fp, h, s0, r0, Lam0, R0, s1, r1, Lam1, R1, mu, newton)


def _potential_numpy(fp, h, s0, r0, Lam0, R0, s1, r1, Lam1, R1, mu, newton):
    """:func:`fluid_potential_step` with NumPy arrays and scipy sparse products (the reference)."""
    s0, s1, R0, R1 = (np.asarray(x, dtype=np.float64) for x in (s0, s1, R0, R1))
    r0, r1, Lam0, Lam1 = (np.asarray(x, dtype=np.float64) for x in (r0, r1, Lam0, Lam1))
    mu = None if mu is None else np.asarray(mu, dtype=np.float64)
    n_nodes, n_lab, nR = len(r0), len(s0), len(R0)
    M = n_lab - 1
    ds = fp.ds
    ia, ib, _ = _topology(n_nodes, fp.periodic, ds, fp.period)
    # strains of each level and their midpoint (§10.3: the strain midpoint, not the strain of a midpoint)
    G0, pa0, pb0 = element_strains(Lam0, r0, ds, fp.periodic, fp.period)
    G1, pa1, pb1 = element_strains(Lam1, r1, ds, fp.periodic, fp.period)
    Gbar = 0.5 * (G0 + G1)
    Gn = np.sqrt(np.sum(Gbar * Gbar, axis=1))
    ghat = Gbar / Gn[:, None]
    T = stretch_map(n_nodes, fp.periodic)
    gamma = T @ Gn
    sbar, Rbar, rbar = 0.5 * (s0 + s1), 0.5 * (R0 + R1), 0.5 * (r0 + r1)

    U, gy, Hy = _potential_in_y(fp, sbar, Rbar, gamma, mu, newton)
    o_R, o_g, o_mu = n_lab, n_lab + nR, n_lab + 2 * nR
    dU_dG = T.T @ gy[o_g:o_mu]
    gGbar = -h * dU_dG[:, None] * ghat          # dL/dGammabar_e; dL/dGamma^l_e is half of it
    Lsum0 = Lam0[ia] + Lam0[ib]
    Lsum1 = Lam1[ia] + Lam1[ib]
    rod0 = _rod_gradient(0.5 * gGbar, Lsum0, pa0, pb0, ia, ib, ds, n_nodes)
    rod1 = _rod_gradient(0.5 * gGbar, Lsum1, pa1, pb1, ia, ib, ds, n_nodes)
    dU_ds = gy[:o_R].copy()

    # gravity on the labels, -g . sum_k mbar_k X(sbar_k; rbar): linear in r with weights summing to one
    g = np.asarray(fp.g, dtype=np.float64)
    grav = bool(np.any(g != 0.0))
    if grav:
        nodes, Nw, dNw, Xb, dXb, d2Xb = centreline_and_weights(sbar, rbar, ds, fp.periodic, fp.period)
        U -= float(np.sum(fp.mbar * (Xb @ g)))
        dU_ds -= fp.mbar * (dXb @ g)
        fr = 0.5 * h * (fp.mbar[:, None] * Nw)[:, :, None] * g[None, None, :]   # d(-h U)/dr^l of node nodes[k, i]
        fnode = _scatter_rows(nodes, fr, n_nodes)
        rod0[:, :3] += fnode
        rod1[:, :3] += fnode

    L = -h * U
    Ds = -0.5 * h * dU_ds
    DR = -0.5 * h * gy[o_R:o_g]
    Dmu = -h * gy[o_mu:] if fp.incompressible else None
    D1 = LevelGradient(rod0, Ds, DR)
    D2 = LevelGradient(rod1, Ds.copy(), DR.copy())
    block = None
    if newton:
        block = _potential_newton(fp, h, n_nodes, n_lab, nR, ia, ib, Lam0, Lam1, pa0, pb0, pa1, pb1, Lsum0, Lsum1,
                                  Gn, ghat, dU_dG, T, Hy, o_R, o_g, o_mu)
        if grav:
            block = _concat_coo(block, _gravity_newton(fp, h, Lam0, nodes, dNw, d2Xb, g, n_nodes, n_lab, nR))
    return StepTerm(L, D1, D2, Dmu, block)


def _concat_coo(*parts):
    return tuple(np.concatenate([p[i] for p in parts]) for i in range(3))


def _chart_columns(Lam0, xi, ia, ib):
    """Per element the 12 x 12 chart map from (b_a, xi_a, b_b, xi_b) to (dr_a, sigma_a, dr_b, sigma_b) at
    level n+1: dr = Lambda^n db, sigma = dcay_{-xi} dxi (Lambda^n cay(xi + dxi) = Lambda^{n+1} cay(sigma) to
    first order, varint/lattice/lie.py)."""
    D = dcay(-xi)
    n_el = len(ia)
    B = np.zeros((n_el, 12, 12))
    B[:, 0:3, 0:3] = Lam0[ia]
    B[:, 3:6, 3:6] = D[ia]
    B[:, 6:9, 6:9] = Lam0[ib]
    B[:, 9:12, 9:12] = D[ib]
    return B


def _potential_newton(fp, h, n_nodes, n_lab, nR, ia, ib, Lam0, Lam1, pa0, pb0, pa1, pb1, Lsum0, Lsum1,
                      Gn, ghat, dU_dG, T, Hy, o_R, o_g, o_mu):
    """d(rotated D1, D_mu)/du by the chain rule through y = (sbar, Rbar, gamma, mu) (module notes)."""
    ds = fp.ds
    M = n_lab - 1
    n_mu = M if fp.incompressible else 0
    off, n = newton_offsets(n_nodes, n_lab, nR, n_mu)
    n_el = len(ia)
    ny = o_mu + n_mu
    # element columns of the rod unknowns, local order (b_a, xi_a, b_b, xi_b)
    ecols = np.concatenate([6 * ia[:, None] + np.arange(6), 6 * ib[:, None] + np.arange(6)], axis=1)
    xi = cay_inv(np.einsum("nji,njk->nik", Lam0, Lam1))
    A0 = _strain_jacobian(Lsum0, pa0, pb0, ds)
    C = np.einsum("eij,ejk->eik", _strain_jacobian(Lsum1, pa1, pb1, ds), _chart_columns(Lam0, xi, ia, ib))
    # dGamma^{n+1}_e/du (3 n_el x n) and dG_e/du = ghat . dGammabar/du = ghat . C / 2
    erow = np.broadcast_to((3 * np.arange(n_el))[:, None, None] + np.arange(3)[None, :, None], C.shape).ravel()
    ecol = np.broadcast_to(ecols[:, None, :], C.shape).ravel()
    Csp = sp.csr_matrix((C.ravel(), (erow, ecol)), shape=(3 * n_el, n))
    dG = sp.csr_matrix((0.5 * np.einsum("ei,eik->ek", ghat, C).ravel(),
                        (np.repeat(np.arange(n_el), 12), ecols.ravel())), shape=(n_el, n))
    # Y = dy/du
    k = np.arange(n_lab)
    j = np.arange(nR)
    Yfix = sp.csr_matrix((np.concatenate([np.full(n_lab, 0.5), np.full(nR, 0.5), np.ones(n_mu)]),
                          (np.concatenate([k, o_R + j, o_mu + np.arange(n_mu)]),
                           np.concatenate([off["s"] + k, off["R"] + j, off["mu"] + np.arange(n_mu)]))), shape=(ny, n))
    Ygam = sp.vstack([sp.csr_matrix((o_g, n)), T @ dG, sp.csr_matrix((n_mu, n))]).tocsr()
    Hsp = sp.csr_matrix((Hy[2], (Hy[0], Hy[1])), shape=(ny, ny))
    HY = (Hsp @ (Yfix + Ygam)).tocsr()
    J_s = -0.5 * h * HY[:o_R]
    J_R = -0.5 * h * HY[o_R:o_g]
    J_mu = -h * HY[o_mu:]
    # rod rows: 1/2 A^nT dL/dGammabar, dL/dGammabar_e = -h dU/dG_e ghat_e
    dUG = T.T @ HY[o_g:o_mu]                                     # d(dU/dG)/du  (n_el x n)
    Ghat = sp.csr_matrix((ghat.ravel(), (np.arange(3 * n_el), np.repeat(np.arange(n_el), 3))), shape=(3 * n_el, n_el))
    # the derivative of ghat_e: (I - ghat ghat^T)/G_e, times dU/dG_e; block diagonal in elements
    P = (np.eye(3)[None] - ghat[:, :, None] * ghat[:, None, :]) * (dU_dG / Gn)[:, None, None]
    prow = np.broadcast_to((3 * np.arange(n_el))[:, None, None] + np.arange(3)[None, :, None], P.shape).ravel()
    pcol = np.broadcast_to((3 * np.arange(n_el))[:, None, None] + np.arange(3)[None, None, :], P.shape).ravel()
    Pblk = sp.csr_matrix((P.ravel(), (prow, pcol)), shape=(3 * n_el, 3 * n_el))
    dgG = -h * (Ghat @ dUG + 0.5 * (Pblk @ Csp))
    # A^nT (6 n_nodes x 3 n_el) with the translational rows rotated into the level-n body frame:
    # Lambda_a^nT (dGamma/ddr_a)^T, i.e. the local columns A0[:, :, 0:3] @ Lambda_a^n
    A0[:, :, 0:3] = A0[:, :, 0:3] @ Lam0[ia]
    A0[:, :, 6:9] = A0[:, :, 6:9] @ Lam0[ib]
    AT = sp.csr_matrix((A0.ravel(), (ecol, erow)), shape=(6 * n_nodes, 3 * n_el))
    J_rod = AT @ (0.5 * dgG)
    J = sp.vstack([J_rod, J_s, J_R, J_mu]).tocoo()
    return J.row.astype(np.int64), J.col.astype(np.int64), J.data


def _gravity_newton(fp, h, Lam0, nodes, dNw, d2Xb, g, n_nodes, n_lab, nR):
    """Newton entries of the labels' gravity: D1_{r_j} = h/2 sum_k mbar_k N_j(sbar_k) g and
    D1_{s_k} = h/2 mbar_k g . X'(sbar_k; rbar), differentiated in s^{n+1} (d sbar = ds/2) and b
    (d rbar_j = Lambda_j^n db_j / 2)."""
    off, _ = newton_offsets(n_nodes, n_lab, nR)
    k = np.arange(n_lab)
    gb = np.einsum("nji,j->ni", Lam0, g)                        # Lambda_j^nT g
    w = 0.25 * h * fp.mbar[:, None] * dNw                        # (M+1, 4)
    vals = (w[:, :, None] * gb[nodes]).ravel()                   # (M+1, 4, 3)
    rod_idx = (6 * nodes[:, :, None] + np.arange(3)).ravel()
    lab = np.broadcast_to(off["s"] + k[:, None, None], (n_lab, 4, 3)).ravel()
    rows = np.concatenate([rod_idx, lab, off["s"] + k])
    cols = np.concatenate([lab, rod_idx, off["s"] + k])
    vals = np.concatenate([vals, vals, 0.25 * h * fp.mbar * (d2Xb @ g)])
    return rows, cols, vals


def fluid_kinetic_chart(s0, r0, Lam0, s1, r1, mbar, h, ds, periodic=False, period=None, newton=False, fast=True):
    """:func:`fluid_kinetic_step` in the stepper's layout: ``StepTerm(L, D1, D2, None, newton)``.

    The kinetic term reads positions only, so its sigma entries are zero and its Newton block has no xi
    columns; the b columns are d/dr^{n+1} Lambda_j^n and the translational rows are rotated by
    Lambda_j^nT, as for the potential (ordering [rod 6/node | s | R | mu]; R and mu rows/columns empty;
    ``nR`` is not known here, so the s block's offset is 6 n_nodes and the returned shape stops there:
    indices are valid in the full ordering of :func:`newton_offsets`).  ``fast``: the compiled kernel
    :func:`_k_kinetic_chart` (default) or the NumPy reference :func:`_kinetic_chart_numpy`.
    """
    if fast:
        return _kinetic_chart_fast(s0, r0, Lam0, s1, r1, mbar, h, ds, periodic, period, newton)
    return _kinetic_chart_numpy(s0, r0, Lam0, s1, r1, mbar, h, ds, periodic, period, newton)


def _kinetic_chart_numpy(s0, r0, Lam0, s1, r1, mbar, h, ds, periodic, period, newton):
    """:func:`fluid_kinetic_chart` from :func:`fluid_kinetic_step`'s label-local Hessians (the reference)."""
    Lam0 = np.asarray(Lam0, dtype=np.float64)
    n_nodes, n_lab = len(r0), len(s0)
    L, index, grad, hess = fluid_kinetic_step(s0, r0, s1, r1, mbar, h, ds, periodic, period, hessian=newton)
    nlev = n_lab + 3 * n_nodes
    g = _scatter(index, grad, 2 * nlev)
    levels = []
    for lev in range(2):
        gl = g[lev * nlev:(lev + 1) * nlev]
        rod = np.zeros((n_nodes, 6))
        rod[:, :3] = gl[n_lab:].reshape(n_nodes, 3)
        levels.append(LevelGradient(rod, gl[:n_lab].copy(), np.zeros(0)))
    block = None
    if newton:
        # the level-n x level-(n+1) quadrant of each label's Hessian (local 0..12 x 13..25), with its
        # position rows rotated by Lambda^nT of their node and its position columns mapped to b by Lambda^n:
        # a label-local 13 x 13 block, written straight into the Newton ordering
        Q = hess[:, :13, 13:]
        nodes0 = (index[:, 1:13:3] - n_lab) // 3
        nodes1 = (index[:, 14:26:3] - 2 * n_lab - 3 * n_nodes) // 3
        L0 = Lam0[nodes0]                                   # (M+1, 4, 3, 3)
        L1 = Lam0[nodes1]
        B = np.empty_like(Q)
        B[:, 0, :] = Q[:, 0, :]
        Qr = Q[:, 1:, :].reshape(n_lab, 4, 3, 13)           # rows: node a, component d
        Qr = np.einsum("kadc,kadv->kacv", L0, Qr)           # Lambda_a^T rows
        B[:, 1:, :] = Qr.reshape(n_lab, 12, 13)
        Bc = B[:, :, 1:].reshape(n_lab, 13, 4, 3)
        B[:, :, 1:] = np.einsum("kuad,kadc->kuac", Bc, L1).reshape(n_lab, 13, 12)
        off_s = 6 * n_nodes
        k = np.arange(n_lab)
        comp = np.arange(3)
        ridx = np.empty((n_lab, 13), np.int64)
        cidx = np.empty((n_lab, 13), np.int64)
        ridx[:, 0] = cidx[:, 0] = off_s + k
        ridx[:, 1:] = (6 * nodes0[:, :, None] + comp).reshape(n_lab, 12)
        cidx[:, 1:] = (6 * nodes1[:, :, None] + comp).reshape(n_lab, 12)
        block = (np.broadcast_to(ridx[:, :, None], B.shape).ravel(), np.broadcast_to(cidx[:, None, :], B.shape).ravel(),
                 B.ravel())
    return StepTerm(L, levels[0], levels[1], None, block)


# ---------------------------------------------------------------------------
# compiled path (numba): the same chain rule, written per element, parcel and label
#
# The NumPy path above chains sparse matrices (about 20 scipy products and conversions per Newton block,
# each with its Python overhead).  The kernels below do the same algebra in loops: the gradient in two
# calls around the equation of state (a Python object), the Newton block in one call that writes the
# y-space Hessian, the column map Y = dy/du and the row map (the rows of D1 and D_mu as combinations of
# dU/dy) as short CSR lists and multiplies them out with a marker-array sparse product (Gustavson's
# algorithm), so every entry of the block is produced once, duplicates summed:
#
#     J = Ry^T (Hy Y) + per-element terms,
#
# with, per y-index: label k -> row (s_k, -h/2), column (s_k^{n+1}, 1/2); radius j -> (R_j, -h/2), (R_j, 1/2);
# stretch gamma_j -> sum over the elements e at node j of T_je times the element's 12 rod rows
# rho_e = -h/2 A^nT_e ghat_e (translations rotated by Lambda^nT) and 12 chart columns
# kappa_e = 1/2 ghat_e^T A^{n+1}_e B_e (B_e the chart map of `_chart_columns`); mu_k -> (mu_k, -h), (mu_k, 1).
# The per-element term is the derivative of ghat_e: -h/4 A^nT_e (I - ghat ghat^T) (dU/dG_e / G_e) A^{n+1}_e B_e.
# These are the factors of `_potential_newton` (Yfix + Ygam, Ghat T^T, Pblk Csp, AT), element by element.

from numba import njit  # noqa: E402

from ..lattice.centreline import k_centreline_weights, k_stencil_point, k_stretched_derivatives  # noqa: E402
from ..lattice.lie import k_hat  # noqa: E402
from .rod import k_chords, k_gamma, k_strain_gradient  # noqa: E402

_EPS = np.finfo(float).eps


def _period_vector(n_nodes, ds, period):
    """The shift d of a periodic tube as a (3,) array (default L e_1, as `_topology`)."""
    if period is None:
        return np.array([n_nodes * ds, 0.0, 0.0])
    return np.ascontiguousarray(period, dtype=np.float64).reshape(3)


@njit(cache=True)
def _k_labels_ok(s, n_nodes, ds, periodic, increasing, on_centreline):
    """True when the compiled kernels may read labels ``s``: finite; strictly increasing with a periodic
    span of at most two periods (``increasing``: what `label_problem(tube=False)` asks of the volumes);
    on a closed centreline of at least 3 nodes within round-off (``on_centreline``: what
    `centreline_weights` asks).  False sends the call to the NumPy path, which raises the precise error."""
    n = s.shape[0]
    L = ds * (n_nodes if periodic else n_nodes - 1)
    for k in range(n):
        if not np.isfinite(s[k]):
            return False
    if increasing:
        for k in range(n - 1):
            if not s[k + 1] > s[k]:
                return False
        if periodic and n > 0 and s[n - 1] - s[0] > 2.0 * L:
            return False
    if on_centreline and not periodic:
        if n_nodes < 3:
            return False
        for k in range(n):
            if s[k] < -8.0 * _EPS * L or s[k] > L * (1.0 + 8.0 * _EPS):
                return False
    return True


@njit(cache=True)
def _k_element_strains(Lam, r, ds, periodic, period, pa, pb, G):
    """`element_strains` into pa, pb, G (n_el, 3) (the rod's kernels, varint.terms.rod.k_chords and k_gamma)."""
    n = r.shape[0]
    dr = np.empty(3)
    for e in range(pa.shape[0]):
        b = (e + 1) % n
        for i in range(3):
            dr[i] = r[b, i] - r[e, i]
            if periodic and e == pa.shape[0] - 1:
                dr[i] += period[i]
        k_chords(Lam[e], Lam[b], dr, pa[e], pb[e])
        k_gamma(Lam[e], Lam[b], dr, ds, G[e])


@njit(cache=True)
def _k_potential_setup(s0, s1, R0, R1, r0, r1, Lam0, Lam1, ds, periodic, period):
    """Midpoint data, strains, stretches and the parcel volumes with their local derivatives:
    ``(sbar, Rbar, rbar, pa0, pb0, pa1, pb1, Gn, ghat, gamma, V, index, gV, HV)`` as in `_potential_numpy`
    (index, gV, HV: `stretched_volume_derivatives`)."""
    n = r0.shape[0]
    n_el = n if periodic else n - 1
    pa0 = np.empty((n_el, 3))
    pb0 = np.empty((n_el, 3))
    pa1 = np.empty((n_el, 3))
    pb1 = np.empty((n_el, 3))
    G0 = np.empty((n_el, 3))
    G1 = np.empty((n_el, 3))
    _k_element_strains(Lam0, r0, ds, periodic, period, pa0, pb0, G0)
    _k_element_strains(Lam1, r1, ds, periodic, period, pa1, pb1, G1)
    Gn = np.empty(n_el)
    ghat = np.empty((n_el, 3))
    gamma = np.zeros(n)
    for e in range(n_el):
        x = 0.0
        for i in range(3):
            ghat[e, i] = 0.5 * (G0[e, i] + G1[e, i])
            x += ghat[e, i] * ghat[e, i]
        Gn[e] = math.sqrt(x)
        for i in range(3):
            ghat[e, i] /= Gn[e]
        for j in (e, (e + 1) % n):
            gamma[j] += k_stretch_weight(j, n, periodic) * Gn[e]
    sbar = 0.5 * (s0 + s1)
    Rbar = 0.5 * (R0 + R1)
    rbar = 0.5 * (r0 + r1)
    nR = Rbar.shape[0]
    M = sbar.shape[0] - 1
    span = 1
    for k in range(M):
        e0 = int(math.floor(sbar[k] / ds))
        e1 = int(math.floor(sbar[k + 1] / ds))
        if not periodic:
            e0 = min(max(e0, 0), nR - 2)
            e1 = min(max(e1, 0), nR - 2)
        span = max(span, e1 - e0 + 1)
    n_loc_nodes = span + 1
    n_loc = 2 + 2 * n_loc_nodes
    V = np.empty(M)
    index = np.full((M, n_loc), -1, np.int64)
    gV = np.zeros((M, n_loc))
    HV = np.zeros((M, n_loc, n_loc))
    k_stretched_derivatives(sbar, Rbar, gamma, ds, periodic, n_loc_nodes, V, index, gV, HV)
    return sbar, Rbar, rbar, pa0, pb0, pa1, pb1, Gn, ghat, gamma, V, index, gV, HV


@njit(cache=True)
def _add_rod_gradient(out, Lam, pa, pb, a, b, gG, ds, d12):
    """`_rod_gradient` of one element: A_e^T gG (varint.terms.rod.k_strain_gradient, into the scratch d12) added into
    nodes a, b of out (n_nodes, 6)."""
    k_strain_gradient(Lam[a], Lam[b], pa, pb, gG, ds, d12)
    for i in range(6):
        out[a, i] += d12[i]
        out[b, i] += d12[6 + i]


@njit(cache=True)
def _centreline_points(s, r, ds, periodic, period):
    """`centreline_and_weights`: ``(nodes, N, dN, d2N, X, X', X'')``, the weights of labels s on r and the centreline
    they give (the period added to the nodes past the end of a periodic tube)."""
    n = r.shape[0]
    m = s.shape[0]
    nodes = np.empty((m, 4), np.int64)
    N, dN, d2N = np.empty((m, 4)), np.empty((m, 4)), np.empty((m, 4))
    X, dX, d2X = np.empty((m, 3)), np.empty((m, 3)), np.empty((m, 3))
    k_centreline_weights(s, n, ds, periodic, nodes, N, dN, d2N)
    for k in range(s.shape[0]):
        e = int(math.floor(s[k] / ds))
        for d in range(3):
            X[k, d] = 0.0
            dX[k, d] = 0.0
            d2X[k, d] = 0.0
        for i in range(4):
            for d in range(3):
                p = k_stencil_point(r, nodes[k, i], e, i, n, periodic, period, d)
                X[k, d] += N[k, i] * p
                dX[k, d] += dN[k, i] * p
                d2X[k, d] += d2N[k, i] * p
    return nodes, N, dN, d2N, X, dX, d2X


@njit(cache=True)
def _k_potential_gradient(h, ds, periodic, period, sbar, Rbar, gamma, rbar, Lam0, Lam1, pa0, pb0, pa1, pb1, ghat,
                          index, gV, c1, p_ext, g, mbar, grav):
    """Level gradients of the potential given c1_k = dU/dV_k (the equation of state's -p_k, or -mu_k):
    ``(U_rest, rod0, rod1, Ds, DR, dU_dG)`` with U_rest the external-pressure and gravity parts of U."""
    n = rbar.shape[0]
    nR = Rbar.shape[0]
    n_lab = sbar.shape[0]
    M = n_lab - 1
    n_el = ghat.shape[0]
    o_R = n_lab
    o_g = n_lab + nR
    gy = np.zeros(n_lab + 2 * nR)
    for k in range(M):
        for i in range(index.shape[1]):
            if index[k, i] >= 0:
                gy[index[k, i]] += c1[k] * gV[k, i]
    U = 0.0
    if p_ext != 0.0:
        # Vol = sum_e ds pi/12 [gamma_a (3a^2 + 2ab + b^2) + gamma_b (a^2 + 2ab + 3b^2)] (`_potential_in_y`)
        c = p_ext * ds * math.pi / 12.0
        for e in range(nR if periodic else nR - 1):
            ja = e
            jb = (e + 1) % nR
            w = k_whole_element(Rbar[ja], Rbar[jb], gamma[ja], gamma[jb])
            U += c * w[0]
            gy[o_R + ja] += c * w[1]
            gy[o_R + jb] += c * w[2]
            gy[o_g + ja] += c * w[3]
            gy[o_g + jb] += c * w[4]
    dU_dG = np.zeros(n_el)
    rod0 = np.zeros((n, 6))
    rod1 = np.zeros((n, 6))
    gG = np.empty(3)
    d12 = np.empty(12)
    for e in range(n_el):
        b = (e + 1) % n
        for j in (e, b):
            dU_dG[e] += k_stretch_weight(j, n, periodic) * gy[o_g + j]
        # dL/dGamma^l_e = 1/2 dL/dGammabar_e = -h/2 dU/dG_e ghat_e
        for i in range(3):
            gG[i] = -0.5 * h * dU_dG[e] * ghat[e, i]
        _add_rod_gradient(rod0, Lam0, pa0[e], pb0[e], e, b, gG, ds, d12)
        _add_rod_gradient(rod1, Lam1, pa1[e], pb1[e], e, b, gG, ds, d12)
    Ds = np.empty(n_lab)
    for k in range(n_lab):
        Ds[k] = -0.5 * h * gy[k]
    DR = np.empty(nR)
    for j in range(nR):
        DR[j] = -0.5 * h * gy[o_R + j]
    if grav:
        # -g . sum_k mbar_k X(sbar_k; rbar): linear in r with weights summing to one
        nodes, N, dN, d2N, X, dX, d2X = _centreline_points(sbar, rbar, ds, periodic, period)
        for k in range(n_lab):
            U -= mbar[k] * (X[k, 0] * g[0] + X[k, 1] * g[1] + X[k, 2] * g[2])
            Ds[k] += 0.5 * h * mbar[k] * (dX[k, 0] * g[0] + dX[k, 1] * g[1] + dX[k, 2] * g[2])
            for i in range(4):
                for d in range(3):
                    f = 0.5 * h * mbar[k] * N[k, i] * g[d]
                    rod0[nodes[k, i], d] += f
                    rod1[nodes[k, i], d] += f
    return U, rod0, rod1, Ds, DR, dU_dG


# -- sparse helpers: CSR lists with duplicates, and their product with duplicates summed


@njit(cache=True)
def _k_coo_to_csr(rows, cols, vals, n_rows):
    """CSR (ptr, idx, val) of COO triplets, by a counting sort on the rows; duplicates are kept (the
    product below sums them)."""
    ptr = np.zeros(n_rows + 1, np.int64)
    for t in range(rows.shape[0]):
        ptr[rows[t] + 1] += 1
    for i in range(n_rows):
        ptr[i + 1] += ptr[i]
    fill = ptr[:-1].copy()
    idx = np.empty(rows.shape[0], np.int64)
    val = np.empty(rows.shape[0])
    for t in range(rows.shape[0]):
        p = fill[rows[t]]
        idx[p] = cols[t]
        val[p] = vals[t]
        fill[rows[t]] = p + 1
    return ptr, idx, val


@njit(cache=True)
def _k_csr_sum_duplicates(ptr, idx, val, n_cols, drop_zeros):
    """The same matrix with each row's duplicates summed (a marker array) and, if ``drop_zeros``, its exact
    zeros removed (a liquid's Hessian has structural zeros, stretch x stretch, that would otherwise be
    carried through both products)."""
    n = ptr.shape[0] - 1
    pos = np.full(n_cols, -1, np.int64)
    optr = np.zeros(n + 1, np.int64)
    oidx = np.empty(idx.shape[0], np.int64)
    oval = np.empty(idx.shape[0])
    p = 0
    for i in range(n):
        start = p
        for q in range(ptr[i], ptr[i + 1]):
            j = idx[q]
            if pos[j] < start:
                pos[j] = p
                oidx[p] = j
                oval[p] = val[q]
                p += 1
            else:
                oval[pos[j]] += val[q]
        end = p
        for q in range(start, end):
            pos[oidx[q]] = -1   # compaction below may move the next rows' start under these positions
        if drop_zeros:
            p = start
            for q in range(start, end):
                if oval[q] != 0.0:
                    oidx[p] = oidx[q]
                    oval[p] = oval[q]
                    p += 1
        optr[i + 1] = p
    return optr, oidx[:p], oval[:p]


@njit(cache=True)
def _k_spgemm(Ap, Ai, Ax, Bp, Bi, Bx, n_cols):
    """C = A B for CSR A (n x m) and B (m x n_cols) (duplicates allowed in both): Gustavson's row-by-row
    product with a marker array, so each (row, column) of C appears once.  Two passes: the pattern, then
    the values.  Returns CSR (ptr, idx, val), columns in order of first appearance within a row."""
    n = Ap.shape[0] - 1
    mark = np.full(n_cols, -1, np.int64)
    Cp = np.zeros(n + 1, np.int64)
    for i in range(n):
        cnt = 0
        for a in range(Ap[i], Ap[i + 1]):
            k = Ai[a]
            for b in range(Bp[k], Bp[k + 1]):
                j = Bi[b]
                if mark[j] != i:
                    mark[j] = i
                    cnt += 1
        Cp[i + 1] = Cp[i] + cnt
    Ci = np.empty(Cp[n], np.int64)
    Cx = np.zeros(Cp[n])
    pos = np.full(n_cols, -1, np.int64)   # where column j sits in C; stale when below the row's start
    for i in range(n):
        start = Cp[i]
        p = start
        for a in range(Ap[i], Ap[i + 1]):
            k = Ai[a]
            x = Ax[a]
            for b in range(Bp[k], Bp[k + 1]):
                j = Bi[b]
                if pos[j] < start:
                    pos[j] = p
                    Ci[p] = j
                    Cx[p] = x * Bx[b]
                    p += 1
                else:
                    Cx[pos[j]] += x * Bx[b]
    return Cp, Ci, Cx


@njit(cache=True)
def _mm3(A, B, sign, out, col):
    """out[:, col:col+3] = sign A B for 3 x 3 A, B (loops: numba's @ calls BLAS, slow at this size)."""
    for i in range(3):
        for k in range(3):
            out[i, col + k] = sign * (A[i, 0] * B[0, k] + A[i, 1] * B[1, k] + A[i, 2] * B[2, k])


@njit(cache=True)
def _k_potential_newton(h, ds, periodic, period, n_mu, sbar, Rbar, gamma, rbar, Lam0, Lam1, pa0, pb0, pa1, pb1,
                        Gn, ghat, dU_dG, index, gV, HV, c1, c2, p_ext, g, mbar, grav):
    """The potential's Newton block (see the section notes) as COO (rows, cols, vals).

    c1_k, c2_k are dU/dV_k and d2U/dV_k^2 of the fluid term (equation of state: -p_k and -dp_k/dV_k;
    incompressible: -mu_k and 0, plus the mu rows and columns -dV_k/dy)."""
    n = rbar.shape[0]
    nR = Rbar.shape[0]
    n_lab = sbar.shape[0]
    M = n_lab - 1
    n_el = Gn.shape[0]
    n_loc = index.shape[1]
    o_R, o_g, o_mu = n_lab, n_lab + nR, n_lab + 2 * nR
    ny = o_mu + n_mu
    off_s, off_R, off_mu = 6 * n, 6 * n + n_lab, 6 * n + n_lab + nR
    nu = off_mu + n_mu

    # -- Hy: the Hessian of U in y = (sbar, Rbar, gamma, mu), as COO with duplicates
    n_pe = nR if periodic else nR - 1
    cap = M * n_loc * n_loc + (2 * M * n_loc if n_mu > 0 else 0) + (12 * n_pe if p_ext != 0.0 else 0)
    hr = np.empty(cap, np.int64)
    hc = np.empty(cap, np.int64)
    hv = np.empty(cap)
    t = 0
    for k in range(M):
        for i in range(n_loc):
            yi = index[k, i]
            if yi < 0:
                continue
            for j in range(n_loc):
                yj = index[k, j]
                if yj < 0:
                    continue
                hr[t] = yi
                hc[t] = yj
                hv[t] = c2[k] * gV[k, i] * gV[k, j] + c1[k] * HV[k, i, j]
                t += 1
            if n_mu > 0:  # -mu_k (V_k - V0_k): d2/dmu_k dy = -dV_k/dy
                hr[t] = o_mu + k
                hc[t] = yi
                hv[t] = -gV[k, i]
                hr[t + 1] = yi
                hc[t + 1] = o_mu + k
                hv[t + 1] = -gV[k, i]
                t += 2
    if p_ext != 0.0:
        c = p_ext * ds * math.pi / 12.0
        for e in range(n_pe):
            ja = e
            jb = (e + 1) % nR
            w = k_whole_element(Rbar[ja], Rbar[jb], gamma[ja], gamma[jb])
            iRa, iRb, iga, igb = o_R + ja, o_R + jb, o_g + ja, o_g + jb
            # (R_a, R_a), (R_b, R_b) once; the off-diagonal pairs both ways (`_potential_in_y`)
            pr = (iRa, iRb, iRa, iRb, iRa, iga, iRa, igb, iRb, iga, iRb, igb)
            pc = (iRa, iRb, iRb, iRa, iga, iRa, igb, iRa, iga, iRb, igb, iRb)
            pv = (c * w[5], c * w[6], c * w[7], c * w[7], c * w[8], c * w[8], c * w[9], c * w[9], c * w[10], c * w[10],
                  c * w[11], c * w[11])
            for q in range(12):
                hr[t] = pr[q]
                hc[t] = pc[q]
                hv[t] = pv[q]
                t += 1
    Hp, Hi, Hx = _k_coo_to_csr(hr[:t], hc[:t], hv[:t], ny)
    Hp, Hi, Hx = _k_csr_sum_duplicates(Hp, Hi, Hx, ny, True)

    # -- per element: rho_e (rows), kappa_e (columns), E_e (the derivative of ghat_e)
    Dc = np.empty((n, 3, 3))            # dcay(-xi_j), xi_j = cay^-1(Lambda_j^nT Lambda_j^{n+1})
    Q = np.empty((3, 3))
    for j in range(n):
        for i in range(3):
            for k in range(3):
                Q[i, k] = Lam0[j, 0, i] * Lam1[j, 0, k] + Lam0[j, 1, i] * Lam1[j, 1, k] + Lam0[j, 2, i] * Lam1[j, 2, k]
        f = 2.0 / (1.0 + Q[0, 0] + Q[1, 1] + Q[2, 2])
        x, y, z = f * (Q[2, 1] - Q[1, 2]), f * (Q[0, 2] - Q[2, 0]), f * (Q[1, 0] - Q[0, 1])
        cc = 4.0 / (4.0 + x * x + y * y + z * z)
        # dcay(-xi) = cc (I - hat(xi)/2)
        Dc[j, 0, 0] = cc
        Dc[j, 1, 1] = cc
        Dc[j, 2, 2] = cc
        Dc[j, 0, 1] = cc * 0.5 * z
        Dc[j, 1, 0] = -cc * 0.5 * z
        Dc[j, 0, 2] = -cc * 0.5 * y
        Dc[j, 2, 0] = cc * 0.5 * y
        Dc[j, 1, 2] = cc * 0.5 * x
        Dc[j, 2, 1] = -cc * 0.5 * x
    rho = np.empty((n_el, 12))
    kappa = np.empty((n_el, 12))
    E = np.empty((n_el, 12, 12))
    ecol = np.empty((n_el, 12), np.int64)
    A0 = np.empty((3, 12))
    C = np.empty((3, 12))
    P = np.empty((3, 3))
    PC = np.empty((3, 12))
    LT0 = np.empty((3, 3))
    LT1 = np.empty((3, 3))
    ha = np.empty((3, 3))
    hb = np.empty((3, 3))
    for e in range(n_el):
        a = e
        b = (e + 1) % n
        for i in range(3):
            for k in range(3):
                LT0[i, k] = (Lam0[a, k, i] + Lam0[b, k, i]) / (2.0 * ds)
                LT1[i, k] = (Lam1[a, k, i] + Lam1[b, k, i]) / (2.0 * ds)
        # A^n_e with its translational columns rotated by Lambda^n (rows of D1 in the level-n body frame)
        _mm3(LT0, Lam0[a], -1.0, A0, 0)
        _mm3(LT0, Lam0[b], 1.0, A0, 6)
        k_hat(pa0[e], 0.5 / ds, ha)
        k_hat(pb0[e], 0.5 / ds, hb)
        A0[:, 3:6] = ha
        A0[:, 9:12] = hb
        # A^{n+1}_e B_e: translations b -> Lambda^n b, rotations xi -> sigma = dcay(-xi) dxi
        _mm3(LT1, Lam0[a], -1.0, C, 0)
        _mm3(LT1, Lam0[b], 1.0, C, 6)
        k_hat(pa1[e], 0.5 / ds, ha)
        k_hat(pb1[e], 0.5 / ds, hb)
        _mm3(ha, Dc[a], 1.0, C, 3)
        _mm3(hb, Dc[b], 1.0, C, 9)
        w = dU_dG[e] / Gn[e]
        for i in range(3):
            for k in range(3):
                P[i, k] = w * ((1.0 if i == k else 0.0) - ghat[e, i] * ghat[e, k])
        for i in range(3):
            for m in range(12):
                PC[i, m] = P[i, 0] * C[0, m] + P[i, 1] * C[1, m] + P[i, 2] * C[2, m]
        for l in range(12):
            r_ = 0.0
            k_ = 0.0
            for i in range(3):
                r_ += A0[i, l] * ghat[e, i]
                k_ += ghat[e, i] * C[i, l]
            rho[e, l] = -0.5 * h * r_
            kappa[e, l] = 0.5 * k_
            for m in range(12):
                v = 0.0
                for i in range(3):
                    v += A0[i, l] * PC[i, m]
                E[e, l, m] = -0.25 * h * v
        for l in range(6):
            ecol[e, l] = 6 * a + l
            ecol[e, 6 + l] = 6 * b + l

    # -- Y = dy/du as CSR over y (duplicates allowed)
    cap = n_lab + nR + n_mu + 2 * 12 * n_el
    yr = np.empty(cap, np.int64)
    yc = np.empty(cap, np.int64)
    yv = np.empty(cap)
    t = 0
    for k in range(n_lab):
        yr[t], yc[t], yv[t] = k, off_s + k, 0.5
        t += 1
    for j in range(nR):
        yr[t], yc[t], yv[t] = o_R + j, off_R + j, 0.5
        t += 1
    for k in range(n_mu):
        yr[t], yc[t], yv[t] = o_mu + k, off_mu + k, 1.0
        t += 1
    for e in range(n_el):
        for j in (e, (e + 1) % n):
            wj = k_stretch_weight(j, n, periodic)
            for l in range(12):
                yr[t], yc[t], yv[t] = o_g + j, ecol[e, l], wj * kappa[e, l]
                t += 1
    Yp, Yi, Yx = _k_coo_to_csr(yr[:t], yc[:t], yv[:t], ny)
    Yp, Yi, Yx = _k_csr_sum_duplicates(Yp, Yi, Yx, nu, False)   # elements e-1, e share node e: 24 -> 18

    # -- K = Hy Y, then the element rows E_e appended (rows ny + 12 e + l)
    Kp, Ki, Kx = _k_spgemm(Hp, Hi, Hx, Yp, Yi, Yx, nu)
    nK = Kp[ny]
    Kp2 = np.empty(ny + 12 * n_el + 1, np.int64)
    Kp2[:ny + 1] = Kp
    Ki2 = np.empty(nK + 144 * n_el, np.int64)
    Kx2 = np.empty(nK + 144 * n_el)
    Ki2[:nK] = Ki
    Kx2[:nK] = Kx
    p = nK
    for e in range(n_el):
        for l in range(12):
            for m in range(12):
                Ki2[p] = ecol[e, m]
                Kx2[p] = E[e, l, m]
                p += 1
            Kp2[ny + 12 * e + l + 1] = p

    # -- the row map Ry^T: each residual row as a combination of rows of K
    cap = n_lab + nR + n_mu + 3 * 12 * n_el
    rr = np.empty(cap, np.int64)
    rc = np.empty(cap, np.int64)
    rv = np.empty(cap)
    t = 0
    for k in range(n_lab):
        rr[t], rc[t], rv[t] = off_s + k, k, -0.5 * h
        t += 1
    for j in range(nR):
        rr[t], rc[t], rv[t] = off_R + j, o_R + j, -0.5 * h
        t += 1
    for k in range(n_mu):
        rr[t], rc[t], rv[t] = off_mu + k, o_mu + k, -h
        t += 1
    for e in range(n_el):
        for l in range(12):
            row = ecol[e, l]
            for j in (e, (e + 1) % n):
                rr[t], rc[t], rv[t] = row, o_g + j, k_stretch_weight(j, n, periodic) * rho[e, l]
                t += 1
            rr[t], rc[t], rv[t] = row, ny + 12 * e + l, 1.0
            t += 1
    Rp, Ri, Rx = _k_coo_to_csr(rr[:t], rc[:t], rv[:t], nu)
    Rp, Ri, Rx = _k_csr_sum_duplicates(Rp, Ri, Rx, ny + 12 * n_el, False)
    Jp, Ji, Jx = _k_spgemm(Rp, Ri, Rx, Kp2, Ki2, Kx2, nu)

    # -- COO, with the labels' gravity appended (`_gravity_newton`)
    nJ = Jp[nu]
    n_grav = 25 * n_lab if grav else 0
    rows = np.empty(nJ + n_grav, np.int64)
    cols = np.empty(nJ + n_grav, np.int64)
    vals = np.empty(nJ + n_grav)
    for i in range(nu):
        for q in range(Jp[i], Jp[i + 1]):
            rows[q] = i
    cols[:nJ] = Ji
    vals[:nJ] = Jx
    if grav:
        nodes, N, dN, d2N, X, dX, d2X = _centreline_points(sbar, rbar, ds, periodic, period)
        q = nJ
        for k in range(n_lab):
            for i in range(4):
                j = nodes[k, i]
                w = 0.25 * h * mbar[k] * dN[k, i]
                for d in range(3):
                    gb = Lam0[j, 0, d] * g[0] + Lam0[j, 1, d] * g[1] + Lam0[j, 2, d] * g[2]
                    rows[q], cols[q], vals[q] = 6 * j + d, off_s + k, w * gb
                    rows[q + 1], cols[q + 1], vals[q + 1] = off_s + k, 6 * j + d, w * gb
                    q += 2
            rows[q], cols[q] = off_s + k, off_s + k
            vals[q] = 0.25 * h * mbar[k] * (d2X[k, 0] * g[0] + d2X[k, 1] * g[1] + d2X[k, 2] * g[2])
            q += 1
    return rows, cols, vals


def _potential_fast(fp, h, s0, r0, Lam0, R0, s1, r1, Lam1, R1, mu, newton):
    """:func:`fluid_potential_step` by the compiled kernels (labels the kernels cannot read go to the
    NumPy path, which raises the precise error)."""
    s0, s1, R0, R1 = (np.ascontiguousarray(x, dtype=np.float64) for x in (s0, s1, R0, R1))
    r0, r1, Lam0, Lam1 = (np.ascontiguousarray(x, dtype=np.float64) for x in (r0, r1, Lam0, Lam1))
    mu = None if mu is None else np.ascontiguousarray(mu, dtype=np.float64)
    n_nodes, n_lab = len(r0), len(s0)
    g = np.ascontiguousarray(fp.g, dtype=np.float64)
    grav = bool(np.any(g != 0.0))
    sbar = 0.5 * (s0 + s1)
    if not _k_labels_ok(sbar, n_nodes, fp.ds, fp.periodic, True, grav):
        return _potential_numpy(fp, h, s0, r0, Lam0, R0, s1, r1, Lam1, R1, mu, newton)
    period = _period_vector(n_nodes, fp.ds, fp.period)
    (sbar, Rbar, rbar, pa0, pb0, pa1, pb1, Gn, ghat, gamma, V, index, gV, HV) = _k_potential_setup(
        s0, s1, R0, R1, r0, r1, Lam0, Lam1, fp.ds, fp.periodic, period)
    if fp.incompressible:
        U = -float(np.dot(mu, V - fp.V0))
        c1, c2 = -mu, np.zeros(len(V))
    else:
        U = float(np.sum(fp.eos.psi(V, fp.m, fp.S)))
        c1, c2 = (np.ascontiguousarray(x, dtype=np.float64) for x in fp.eos.dpsi(V, fp.m, fp.S))
    mbar = np.ascontiguousarray(fp.mbar, dtype=np.float64)
    U_rest, rod0, rod1, Ds, DR, dU_dG = _k_potential_gradient(
        h, fp.ds, fp.periodic, period, sbar, Rbar, gamma, rbar, Lam0, Lam1, pa0, pb0, pa1, pb1, ghat, index, gV, c1,
        float(fp.p_ext), g, mbar, grav)
    U += U_rest
    Dmu = h * (V - fp.V0) if fp.incompressible else None
    block = None
    if newton:
        block = _k_potential_newton(h, fp.ds, fp.periodic, period, len(V) if fp.incompressible else 0, sbar, Rbar,
                                    gamma, rbar, Lam0, Lam1, pa0, pb0, pa1, pb1, Gn, ghat, dU_dG, index, gV, HV, c1, c2,
                                    float(fp.p_ext), g, mbar, grav)
    return StepTerm(-h * U, LevelGradient(rod0, Ds, DR), LevelGradient(rod1, Ds.copy(), DR.copy()), Dmu, block)


@njit(cache=True)
def _k_kinetic_chart(s0, r0, Lam0, s1, r1, mbar, h, ds, periodic, period, newton):
    """`fluid_kinetic_chart` label by label: ``(L, rod0, s0 gradient, rod1, s1 gradient, rows, cols, vals)``.

    Per label, with D = X^{n+1} - X^n and c = mbar/h, the gradient is c D . dD (dD: -X^n', -N^n_a e_d at
    level n; X^{n+1}', N^{n+1}_a e_d at level n+1), and the Newton block is the level-n x level-(n+1)
    quadrant of c JD^T JD (X is linear in r: no second derivative reaches it), rows rotated by
    Lambda^nT of their node, columns mapped to b by Lambda^n of theirs."""
    n = r0.shape[0]
    n_lab = s0.shape[0]
    nodes0, N0, dN0, _, X0, dX0, _ = _centreline_points(s0, r0, ds, periodic, period)
    nodes1, N1, dN1, _, X1, dX1, _ = _centreline_points(s1, r1, ds, periodic, period)
    rod0 = np.zeros((n, 6))
    rod1 = np.zeros((n, 6))
    gs0 = np.zeros(n_lab)
    gs1 = np.zeros(n_lab)
    nb = 169 * n_lab if newton else 0
    rows = np.empty(nb, np.int64)
    cols = np.empty(nb, np.int64)
    vals = np.empty(nb)
    off_s = 6 * n
    L = 0.0
    D = np.empty(3)
    u0 = np.empty((4, 3))   # Lambda_a^nT X^{n+1}' of the level-n stencil nodes
    u1 = np.empty((4, 3))   # Lambda_b^nT X^n' of the level-(n+1) stencil nodes
    q = 0
    a = b = dr = dc = 0
    for k in range(n_lab):
        c = mbar[k] / h
        DD = 0.0
        d0 = 0.0
        d1 = 0.0
        for d in range(3):
            D[d] = X1[k, d] - X0[k, d]
            DD += D[d] * D[d]
            d0 += D[d] * dX0[k, d]
            d1 += D[d] * dX1[k, d]
        L += 0.5 * c * DD
        gs0[k] = -c * d0
        gs1[k] = c * d1
        for i in range(4):
            for d in range(3):
                rod0[nodes0[k, i], d] -= c * D[d] * N0[k, i]
                rod1[nodes1[k, i], d] += c * D[d] * N1[k, i]
        if not newton:
            continue
        for a in range(4):
            ja = nodes0[k, a]
            jb = nodes1[k, a]
            for d in range(3):
                u0[a, d] = Lam0[ja, 0, d] * dX1[k, 0] + Lam0[ja, 1, d] * dX1[k, 1] + Lam0[ja, 2, d] * dX1[k, 2]
                u1[a, d] = Lam0[jb, 0, d] * dX0[k, 0] + Lam0[jb, 1, d] * dX0[k, 1] + Lam0[jb, 2, d] * dX0[k, 2]
        # local row/column 0: the label; 1 + 3a + d: component d of stencil node a (13 x 13, row-major)
        for ru in range(13):
            if ru == 0:
                row = off_s + k
            else:
                a, dr = (ru - 1) // 3, (ru - 1) % 3
                row = 6 * nodes0[k, a] + dr
            for cv in range(13):
                if cv == 0:
                    col = off_s + k
                else:
                    b, dc = (cv - 1) // 3, (cv - 1) % 3
                    col = 6 * nodes1[k, b] + dc
                if ru == 0 and cv == 0:
                    v = -c * (dX0[k, 0] * dX1[k, 0] + dX0[k, 1] * dX1[k, 1] + dX0[k, 2] * dX1[k, 2])
                elif ru == 0:
                    v = -c * N1[k, b] * u1[b, dc]
                elif cv == 0:
                    v = -c * N0[k, a] * u0[a, dr]
                else:
                    ja = nodes0[k, a]
                    jb = nodes1[k, b]
                    m = Lam0[ja, 0, dr] * Lam0[jb, 0, dc] + Lam0[ja, 1, dr] * Lam0[jb, 1, dc] + \
                        Lam0[ja, 2, dr] * Lam0[jb, 2, dc]
                    v = -c * N0[k, a] * N1[k, b] * m
                rows[q] = row
                cols[q] = col
                vals[q] = v
                q += 1
    return L, rod0, gs0, rod1, gs1, rows, cols, vals


def _kinetic_chart_fast(s0, r0, Lam0, s1, r1, mbar, h, ds, periodic, period, newton):
    """:func:`fluid_kinetic_chart` by :func:`_k_kinetic_chart` (labels off the centreline: the NumPy path)."""
    s0, s1 = (np.ascontiguousarray(x, dtype=np.float64) for x in (s0, s1))
    r0, r1, Lam0 = (np.ascontiguousarray(x, dtype=np.float64) for x in (r0, r1, Lam0))
    n_nodes = len(r0)
    if not (_k_labels_ok(s0, n_nodes, ds, periodic, False, True) and _k_labels_ok(s1, n_nodes, ds, periodic, False, True)):
        return _kinetic_chart_numpy(s0, r0, Lam0, s1, r1, mbar, h, ds, periodic, period, newton)
    L, rod0, gs0, rod1, gs1, rows, cols, vals = _k_kinetic_chart(
        s0, r0, Lam0, s1, r1, np.ascontiguousarray(mbar, dtype=np.float64), float(h), float(ds), bool(periodic),
        _period_vector(n_nodes, ds, period), bool(newton))
    empty = np.zeros(0)
    return StepTerm(L, LevelGradient(rod0, gs0, empty), LevelGradient(rod1, gs1, empty), None,
                    (rows, cols, vals) if newton else None)


# -- one configuration: the static potential's Hessian and the kinetic metric (linear modes, statics) -----------


def fluid_potential_static(fp, s, r, Lam, R, mu=None, hessian=True):
    """The fluid's potential U_f at one configuration, its gradient and its exact Hessian (docs/theory.md §10.4.2).

    U_f = sum_k m_k e(m_k/V_k, S_k)  (or -sum_k mu_k (V_k - V0_k))  + p_ext Vol(R, gamma) - g . sum_k mbar_k X(s_k; r),

    with the stretched volumes of §10.3 at the level's own strains (both levels of a step equal: the
    step's L_pot is then -h U_f).  Derivatives are in the retraction chart r + dr, Lambda cay(sigma), s, R,
    mu, ordering [rod (dr spatial, sigma body) 6/node | s (M+1) | R (nR) | mu (M)] of :func:`newton_offsets`.
    The Hessian is the second derivative of U_f(config retracted by z) at z = 0 (symmetric):

        H = Jy^T H_y Jy  +  sum_e dU/dG_e [ A_e^T (I - ghat ghat^T) A_e / G_e  +  ghat_e . d^2 Gamma_e ]  + gravity,

    y = (s, R, gamma = T G, mu), G_e = |Gamma_e|, A_e the strain Jacobian (`_strain_jacobian`), and the
    second variation of Gamma_e = sum_{i=a,b} cay(sigma_i)^T Lambda_i^T (r_b - r_a + dr_b - dr_a) / (2 ds) from
    cay(sigma)^T = I - hat(sigma) + hat(sigma)^2/2 + O(sigma^3):

        ghat . d^2 Gamma / dsigma_i^2        = [ (p_i ghat^T + ghat p_i^T)/2 - (ghat . p_i) I ] / (2 ds),
        ghat . d^2 Gamma / dsigma_i d dr_b   = hat(ghat) Lambda_i^T / (2 ds) = - (... / d dr_a),

    the geometric stiffness of the pressure (it vanishes where the fluid's pressure equals p_ext).
    Gravity adds -mbar_k g . X''(s_k) on (s_k, s_k) and -mbar_k N_i'(s_k) g on (s_k, r_i).

    Returns ``(U, grad, H)``: grad (n,), H CSR (n, n) (None unless ``hessian``).  The gradient is
    -(D1 + D2) of :func:`fluid_potential_step` at h = 1 with both levels equal (tested).
    """
    s, R = (np.asarray(x, dtype=np.float64) for x in (s, R))
    r, Lam = np.asarray(r, dtype=np.float64), np.asarray(Lam, dtype=np.float64)
    mu = None if mu is None else np.asarray(mu, dtype=np.float64)
    n_nodes, n_lab, nR = len(r), len(s), len(R)
    ds = fp.ds
    n_mu = n_lab - 1 if fp.incompressible else 0
    off, n = newton_offsets(n_nodes, n_lab, nR, n_mu)
    ia, ib, _ = _topology(n_nodes, fp.periodic, ds, fp.period)
    n_el = len(ia)
    G, pa, pb = element_strains(Lam, r, ds, fp.periodic, fp.period)
    Gn = np.sqrt(np.sum(G * G, axis=1))
    ghat = G / Gn[:, None]
    T = stretch_map(n_nodes, fp.periodic)
    gamma = T @ Gn
    U, gy, Hy = _potential_in_y(fp, s, R, gamma, mu, hessian)
    o_R, o_g, o_mu = n_lab, n_lab + nR, n_lab + 2 * nR
    dU_dG = T.T @ gy[o_g:o_mu]
    Lsum = Lam[ia] + Lam[ib]
    grad = np.zeros(n)
    grad[:6 * n_nodes] = _rod_gradient(dU_dG[:, None] * ghat, Lsum, pa, pb, ia, ib, ds, n_nodes).ravel()
    grad[off["s"]:off["s"] + n_lab] = gy[:o_R]
    grad[off["R"]:off["R"] + nR] = gy[o_R:o_g]
    grad[off["mu"]:] = gy[o_mu:]
    g = np.asarray(fp.g, dtype=np.float64)
    grav = bool(np.any(g != 0.0))
    if grav:
        nodes, Nw, dNw, X, dX, d2X = centreline_and_weights(s, r, ds, fp.periodic, fp.period)
        U -= float(np.sum(fp.mbar * (X @ g)))
        grad[off["s"]:off["s"] + n_lab] -= fp.mbar * (dX @ g)
        fr = -(fp.mbar[:, None] * Nw)[:, :, None] * g[None, None, :]
        grad[:6 * n_nodes] += np.concatenate([_scatter_rows(nodes, fr, n_nodes), np.zeros((n_nodes, 3))], axis=1).ravel()
    if not hessian:
        return U, grad, None

    # element columns in the ordering (dr_a, sigma_a, dr_b, sigma_b)
    ecols = np.concatenate([6 * ia[:, None] + np.arange(6), 6 * ib[:, None] + np.arange(6)], axis=1)
    A = _strain_jacobian(Lsum, pa, pb, ds)                                   # (n_el, 3, 12)
    dG = sp.csr_matrix((np.einsum("ei,eik->ek", ghat, A).ravel(), (np.repeat(np.arange(n_el), 12), ecols.ravel())),
                       shape=(n_el, n))
    k, j = np.arange(n_lab), np.arange(nR)
    Yfix = sp.csr_matrix((np.ones(n_lab + nR + n_mu),
                          (np.concatenate([k, o_R + j, o_mu + np.arange(n_mu)]),
                           np.concatenate([off["s"] + k, off["R"] + j, off["mu"] + np.arange(n_mu)]))),
                         shape=(o_mu + n_mu, n))
    Y = (Yfix + sp.vstack([sp.csr_matrix((o_g, n)), T @ dG, sp.csr_matrix((n_mu, n))])).tocsr()
    Hsp = sp.csr_matrix((Hy[2], (Hy[0], Hy[1])), shape=(o_mu + n_mu, o_mu + n_mu))
    H = Y.T @ Hsp @ Y
    # the element stretches' own curvature, weighted by dU/dG_e
    P = np.eye(3)[None] - ghat[:, :, None] * ghat[:, None, :]
    E = np.einsum("eki,ekl,elj->eij", A, P, A) / Gn[:, None, None]
    c = 1.0 / (2.0 * ds)
    for i_loc, p, Li in ((3, pa, Lam[ia]), (9, pb, Lam[ib])):
        sl = slice(i_loc, i_loc + 3)
        gp = np.sum(ghat * p, axis=1)
        E[:, sl, sl] += c * (0.5 * (p[:, :, None] * ghat[:, None, :] + ghat[:, :, None] * p[:, None, :])
                             - gp[:, None, None] * np.eye(3)[None])
        X_ = c * hat(ghat) @ np.swapaxes(Li, 1, 2)                           # d^2/dsigma_i d dr_b
        E[:, sl, 6:9] += X_
        E[:, sl, 0:3] -= X_
        E[:, 6:9, sl] += np.swapaxes(X_, 1, 2)
        E[:, 0:3, sl] -= np.swapaxes(X_, 1, 2)
    E *= dU_dG[:, None, None]
    rows = np.broadcast_to(ecols[:, :, None], E.shape).ravel()
    cols = np.broadcast_to(ecols[:, None, :], E.shape).ravel()
    H = H + sp.csr_matrix((E.ravel(), (rows, cols)), shape=(n, n))
    if grav:
        rod_idx = (6 * nodes[:, :, None] + np.arange(3)).ravel()
        lab = np.broadcast_to(off["s"] + k[:, None, None], (n_lab, 4, 3)).ravel()
        v = (-(fp.mbar[:, None] * dNw)[:, :, None] * g[None, None, :]).ravel()
        H = H + sp.csr_matrix((np.concatenate([v, v, -fp.mbar * (d2X @ g)]),
                               (np.concatenate([rod_idx, lab, off["s"] + k]),
                                np.concatenate([lab, rod_idx, off["s"] + k]))), shape=(n, n))
    return U, grad, H.tocsr()


def fluid_kinetic_metric(s, r, mbar, ds, periodic=False, period=None):
    """The fluid's kinetic metric at one configuration (docs/theory.md §10.5, "Initial momenta"):

        K_f = 1/2 sum_k mbar_k |Xdot_k|^2,   Xdot_k = sum_i N_i(s_k) rdot_i + X'(s_k) sdot_k,

    as the sparse (n_nodes 6 + M+1)^2 matrix Jx^T diag(mbar) Jx in the ordering [rod (rdot, omega) 6/node |
    sdot (M+1)] (the s block of :func:`newton_offsets`; no omega entries: the plug flow has no rotary
    inertia, §10.0).  Returns ``(metric CSR, Jx)``, Jx (3(M+1), n) mapping velocities to the labels' Xdot
    (:func:`kinetic_metric_of` of the centreline's weights).
    """
    nodes, Nw, _, _, dX, _ = centreline_and_weights(s, r, ds, periodic, period)
    return kinetic_metric_of(nodes, Nw, dX, mbar, len(r))


def label_velocity_map(nodes, Nw, dX, n_nodes):
    """Jx (3(M+1) x (6 n_nodes + M+1), CSR): the labels' velocities Xdot_k = sum_a N_a(s_k) rdot_a + X'(s_k) sdot_k from
    the velocities [per node (rdot, omega) | sdot per label], for the weights ``Nw`` of nodes ``nodes`` (M+1, any number
    per label: a Catmull-Rom stencil, or an open end's extended one folded onto the real nodes) and the tangents dX."""
    n_lab, per = nodes.shape
    k = np.repeat(np.arange(n_lab), per)
    rr = (3 * k[:, None] + np.arange(3)).ravel()
    rc = (6 * np.ravel(nodes)[:, None] + np.arange(3)).ravel()
    rv = np.repeat(np.ravel(Nw), 3)
    lr = (3 * np.arange(n_lab)[:, None] + np.arange(3)).ravel()
    lc = np.repeat(6 * n_nodes + np.arange(n_lab), 3)
    return sp.csr_matrix((np.concatenate([rv, np.ravel(dX)]), (np.concatenate([rr, lr]), np.concatenate([rc, lc]))),
                         shape=(3 * n_lab, 6 * n_nodes + n_lab))


def kinetic_metric_of(nodes, Nw, dX, mbar, n_nodes):
    """``(Jx^T diag(mbar) Jx CSR, Jx)``: the fluid's kinetic metric of :func:`fluid_kinetic_metric` from the labels'
    weights (:func:`label_velocity_map`): the one construction, for the modes, the level energy of the coupled tube
    (varint.schemes.monitors) and its open ends' (varint.schemes.open_ends)."""
    Jx = label_velocity_map(nodes, Nw, dX, n_nodes)
    return (Jx.T @ sp.diags(np.repeat(np.asarray(mbar, dtype=np.float64), 3)) @ Jx).tocsr(), Jx
