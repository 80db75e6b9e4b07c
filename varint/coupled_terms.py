"""Terms of the coupled tube's discrete Lagrangian as label-local kernels (docs/theory.md §10.4–10.5).

The fluid's kinetic energy in inertial form (§10.4): over one step n -> n+1,

    L_kin = h sum_k 1/2 mbar_k |X_k^{n+1} - X_k^n|^2 / h^2,     X_k^l = X(s_k^l; r^l),

with X the Catmull–Rom centreline of :mod:`varint.coupled_geometry` and mbar_k the label masses
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

A^l being the rod's strain Jacobian of varint/rod.py (`_k_element`: dGamma/ddr_a = -(La + Lb)^T/(2 ds),
dGamma/dsigma_a = hat(p_a)/(2 ds)).  The Newton block is the chain rule of this through the exact
Hessian of U in y (per-parcel Hessians of varint/coupled_geometry.py `stretched_volume_derivatives`,
the closed-form Hessian of Vol) and the exact first derivatives of Gamma^{n+1} in the chart
r^{n+1} = r^n + Lambda^n b, Lambda^{n+1} = Lambda^n cay(xi) (a xi-variation is the body variation
sigma = dcay_{-xi} dxi, varint/lie.py).  A^n does not depend on the unknowns, so no second derivative of
the strains is needed.  Each piece is element- or parcel-local; they are chained as sparse matrices
whose pattern is the stencil of §10.5 (parcel k: labels k, k+1, radii of nodes e0..e1+1, r and Lambda of
nodes e0-1..e1+2; gravity: label k and its 4 centreline nodes).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp

from .coupled_geometry import centreline_and_weights, stretched_volume_derivatives
from .lie import cay_inv, dcay, hat

__all__ = ["fluid_kinetic_step", "LOCAL_SIZE", "FluidPotential", "LevelGradient", "StepTerm", "fluid_potential_step",
           "fluid_kinetic_chart", "newton_offsets", "stretch_map", "element_strains"]

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
# (as B in varint/model.py).
#
# Newton ordering (rows and columns): [rod: 6 per node, node-major | s: M+1 | R: nR | mu: M].  Rows are
# D1 (level-n variations) with each node's translational rows rotated into its level-n body frame
# (Lambda_j^nT D1_{r_j}), then D_mu; columns are the step unknowns u of docs/theory.md §10.1: per node
# b_j = Lambda_j^nT (r_j^{n+1} - r_j^n) and xi_j = cay^-1(Lambda_j^nT Lambda_j^{n+1}), then s^{n+1},
# R^{n+1}, mu — exactly the convention of varint/rod.py `_k_step_blocks`.


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


def newton_offsets(n_nodes, n_labels, nR, n_mu=0):
    """Offsets of the blocks in the Newton ordering, and its size: ``({"rod", "s", "R", "mu"}, n)``."""
    off = {"rod": 0, "s": 6 * n_nodes, "R": 6 * n_nodes + n_labels, "mu": 6 * n_nodes + n_labels + nR}
    return off, off["mu"] + n_mu


@dataclass(frozen=True)
class FluidPotential:
    """Constant data of the fluid's potential term on the coupled tube (docs/theory.md §10.4.2).

    ``eos`` is an equation of state in the form of varint/thermo.py (``psi(V, m, S)`` the parcel internal
    energy m e(m/V, S), ``dpsi(V, m, S)`` its first and second V-derivatives, -p and -dp/dV); ``eos=None``
    means incompressible, with reference volumes ``V0`` and multipliers mu.  ``mbar`` (M+1,) are the label
    masses of §10.1 (closed ends included: mbar_0 = m_0/2, mbar_M = m_{M-1}/2; periodic: label M is
    label 0 shifted by the period, so mbar_0 = (m_{M-1} + m_0)/2 and mbar_M = 0 — counted once, as
    varint/tube.py does), ``g`` the gravity vector, ``period`` the shift d of a periodic tube (default
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
    body-frame chords p_a = Lambda_a^T (r_b - r_a), p_b = Lambda_b^T (r_b - r_a): ``(Gamma, p_a, p_b)``."""
    Lam = np.asarray(Lam, dtype=np.float64)
    r = np.asarray(r, dtype=np.float64)
    ia, ib, shift = _topology(len(r), periodic, ds, period)
    dr = r[ib] - r[ia] + shift
    pa = np.einsum("eki,ek->ei", Lam[ia], dr)
    pb = np.einsum("eki,ek->ei", Lam[ib], dr)
    return 0.5 * (pa + pb) / ds, pa, pb


@lru_cache(maxsize=16)
def stretch_map(n_nodes, periodic=False):
    """The linear map T (nR x n_el, sparse) with gamma = T G: the nodal stretch of §10.3 (mean of the
    adjacent elements; a closed end node takes its only element's).  Cached: do not modify it."""
    n_el = n_nodes if periodic else n_nodes - 1
    e = np.arange(n_el)
    rows = np.concatenate([e, (e + 1) % n_nodes])
    vals = np.full(2 * n_el, 0.5)
    if not periodic:
        vals[0] = vals[-1] = 1.0  # node 0 (from element 0) and node N (from element N-1)
    return sp.csr_matrix((vals, (rows, np.concatenate([e, e]))), shape=(n_nodes, n_el))


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
        # varint/coupled_geometry.py, the whole element (§10.3)
        ia, ib, _ = _topology(nR, fp.periodic, fp.ds, None)
        a, b, ga, gb = Rbar[ia], Rbar[ib], gamma[ia], gamma[ib]
        c = fp.p_ext * fp.ds * np.pi / 12.0
        U += float(np.sum(c * (ga * (3 * a * a + 2 * a * b + b * b) + gb * (a * a + 2 * a * b + 3 * b * b))))
        iR_a, iR_b, ig_a, ig_b = o_R + ia, o_R + ib, o_g + ia, o_g + ib
        grad += _scatter(np.concatenate([iR_a, iR_b, ig_a, ig_b]),
                         np.concatenate([c * (ga * (6 * a + 2 * b) + gb * (2 * a + 2 * b)),
                                         c * (ga * (2 * a + 2 * b) + gb * (2 * a + 6 * b)),
                                         c * (3 * a * a + 2 * a * b + b * b), c * (a * a + 2 * a * b + 3 * b * b)]), ny)
        if want_hessian:
            pairs = [(iR_a, iR_a, 6 * ga + 2 * gb), (iR_b, iR_b, 2 * ga + 6 * gb), (iR_a, iR_b, 2 * ga + 2 * gb),
                     (iR_a, ig_a, 6 * a + 2 * b), (iR_a, ig_b, 2 * a + 2 * b),
                     (iR_b, ig_a, 2 * a + 2 * b), (iR_b, ig_b, 2 * a + 6 * b)]
            for i, j, v in pairs:
                rows += [i] if i is j else [i, j]
                cols += [j] if i is j else [j, i]
                vals += [c * v] if i is j else [c * v, c * v]
    H = None
    if want_hessian:
        H = (np.concatenate(rows).astype(np.int64), np.concatenate(cols).astype(np.int64), np.concatenate(vals))
    return U, grad, H


def fluid_potential_step(fp, h, s0, r0, Lam0, R0, s1, r1, Lam1, R1, mu=None, newton=False):
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
    """
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
    first order, varint/lie.py)."""
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


def fluid_kinetic_chart(s0, r0, Lam0, s1, r1, mbar, h, ds, periodic=False, period=None, newton=False):
    """:func:`fluid_kinetic_step` in the stepper's layout: ``StepTerm(L, D1, D2, None, newton)``.

    The kinetic term reads positions only, so its sigma entries are zero and its Newton block has no xi
    columns; the b columns are d/dr^{n+1} Lambda_j^n and the translational rows are rotated by
    Lambda_j^nT, as for the potential (ordering [rod 6/node | s | R | mu]; R and mu rows/columns empty;
    ``nR`` is not known here, so the s block's offset is 6 n_nodes and the returned shape stops there:
    indices are valid in the full ordering of :func:`newton_offsets`).
    """
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
