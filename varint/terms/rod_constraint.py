"""The inextensible, unshearable rod: the holonomic constraint Gamma = chi with multipliers (docs/theory.md §9a).

The paper's ``inext_unshear_norot`` limit of the rod: no stretch and no shear, Gamma = Lambda^T r' = E_1.
On the lattice the stretch-shear energy is replaced by a constraint on each element's strain at the levels
(SHAKE, as the incompressible liquid's volumes are, docs/theory.md §10.12):

    S = sum_n [ L_d'(q_n, q_{n+1}) - h sum_e ds lambda_e^n . (Gamma_e(q_n) - chi) ],

with the multipliers lambda_e^n (the internal force n of the element, body frame) level unknowns.  A step solves
(q_{n+1}, lambda^n): the force -h ds G(q_n)^T lambda^n acts at the known level and the rows are
-h ds (Gamma_e(q_{n+1}) - chi) (:func:`level_constraint_step`), so Gamma = chi at every level to the solver
tolerance.  The element kernel is written for the strain midpoint Gammabar = (Gamma^n + Gamma^{n+1}) / 2 (the
earlier form, which steps the same trajectory, docs/theory.md §9a); the level form calls it with both of its
levels at one configuration.  The stiff axial and shear modes are then absent, not merely unresolved
(docs/theory.md §12).

A planar rod (x-y plane) has Gamma_3 = 0 identically; only Gamma_1, Gamma_2 are constrained there.

Kernels are element-local and exact: :func:`_k_constraint_element` returns an element's value, its
gradients with respect to the Lie-group variations of both levels (dr spatial, sigma body, per node:
layout [dr_a, sigma_a, dr_b, sigma_b]) and D_lambda; :func:`_k_constraint_blocks` the Newton blocks by
complex step of that analytic gradient in the step chart (b, xi) and analytically in lambda.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..lattice.lie import k_cay
from .rod import (CHI, k_body_rows, k_chart_column, k_chords, k_gamma_mid, k_load_element, k_strain_gradients, _k_config_column,
                  _k_mm)

__all__ = ["constraint_step", "level_constraint_step", "constraint_blocks", "element_strain_residual", "constraint_jacobian", "constraint_static"]


@njit(cache=True)
def _k_constraint_element(h, ds, L0a, L0b, r0a, r0b, L1a, L1b, r1a, r1b, lam, ncomp, D1, D2, Dl, lev_lo, lev_hi):
    """-h ds lam . (Gammabar - chi) of one element (returned) and its exact gradients.

    D1 (12) / D2 (12): d/d(dr, sigma) of the level-n / level-(n+1) variations; Dl (3): d/d lam.  Only the
    first ``ncomp`` strain components are constrained (3 in space, 2 in the plane).  One scalar type for
    every array (float64, or complex128 for complex steps).
    """
    pa0 = np.empty(3, L0a.dtype)
    pb0 = np.empty(3, L0a.dtype)
    pa1 = np.empty(3, L0a.dtype)
    pb1 = np.empty(3, L0a.dtype)
    gG = np.empty(3, L0a.dtype)
    d0 = np.empty(3, L0a.dtype)
    d1 = np.empty(3, L0a.dtype)
    for i in range(3):
        d0[i] = r0b[i] - r0a[i]
        d1[i] = r1b[i] - r1a[i]
    k_chords(L0a, L0b, d0, pa0, pb0)
    k_chords(L1a, L1b, d1, pa1, pb1)
    c = h * ds
    val = 0.0 * lam[0]
    for i in range(3):
        g = k_gamma_mid(pa0[i], pb0[i], pa1[i], pb1[i], ds) - CHI[i]
        if i < ncomp:
            val = val - c * lam[i] * g
            Dl[i] = -c * g
            gG[i] = -0.5 * c * lam[i]  # d value / d Gamma^l (the same for both levels)
        else:
            Dl[i] = 0.0 * g
            gG[i] = 0.0 * g
    k_strain_gradients(L0a, L0b, L1a, L1b, pa0, pb0, pa1, pb1, gG, ds, lev_lo, lev_hi, D1, D2)
    return val


@njit(cache=True)
def _k_constraint_step(h, ds, Lam_n, r_n, Lam_1, r_1, lam, ncomp, lev_lo, lev_hi, D1, D2, Dl):
    """Sum over elements into D1, D2 (N+1, 6) and Dl (N, 3); returns the value."""
    N = Lam_n.shape[0] - 1
    e1 = np.empty(12)
    e2 = np.empty(12)
    dl = np.empty(3)
    D1[:] = 0.0
    D2[:] = 0.0
    val = 0.0
    for e in range(N):
        val += _k_constraint_element(h, ds, Lam_n[e], Lam_n[e + 1], r_n[e], r_n[e + 1], Lam_1[e], Lam_1[e + 1],
                                     r_1[e], r_1[e + 1], lam[e], ncomp, e1, e2, dl, lev_lo, lev_hi)
        for i in range(6):
            D1[e, i] += e1[i]
            D1[e + 1, i] += e1[6 + i]
            D2[e, i] += e2[i]
            D2[e + 1, i] += e2[6 + i]
        for i in range(3):
            Dl[e, i] = dl[i]
    return val


@njit(cache=True)
def _constraint_scratch():
    """Complex work arrays of the constraint's complex-step blocks: (M (6, 3, 3), V (8, 3), e1 (12), e2 (12))."""
    c = np.complex128
    return np.empty((6, 3, 3), c), np.empty((8, 3), c), np.empty(12, c), np.empty(12, c)


@njit(cache=True)
def _k_constraint_blocks(h, ds, Lam_n, r_n, xi, r_1, lam, ncomp, mask, eps, at_levels, blocks, lam_blocks, row_blocks):
    """Newton blocks of one element e:

    ``blocks[e, :, k]`` = d(rotated D1 of the element)/d u_k, u = (b_a, xi_a, b_b, xi_b) (complex step of the
    analytic gradient; translational rows in the level-n body frame of their node, as the rod's);
    ``lam_blocks[e, :, i]`` = d(rotated D1)/d lam_e,i (analytic: D1 is linear in lam);
    ``row_blocks[e, i, k]`` = d(D_lam_e,i)/d u_k (complex step).  Columns off the ``mask`` are left zero.

    ``at_levels`` (SHAKE, docs/theory.md §9a): the term is -h ds lam_n . (Gamma(q_n) - chi); its force acts at the
    known level n (``blocks`` = 0, ``lam_blocks`` from level n) and the row is -h ds (Gamma(q_{n+1}) - chi), the
    D_lam of the next step's term (``row_blocks`` from level n+1 alone).
    """
    N = Lam_n.shape[0] - 1
    M, V, e1, e2 = _constraint_scratch()
    La0, Lb0, La1, Lb1, Ca, Cb = M[0], M[1], M[2], M[3], M[4], M[5]
    ra0, rb0, qa, qb, xa, xb, lc, dl = V[0], V[1], V[2], V[3], V[4], V[5], V[6], V[7]
    col = np.empty(12)
    inv = 1.0 / eps
    for e in range(N):
        k_load_element(Lam_n, r_n, e, La0, Lb0, ra0, rb0)
        for i in range(3):
            lc[i] = lam[e, i]
        for k in range(12):
            if not mask[e + k // 6, k % 6]:
                for i in range(12):
                    blocks[e, i, k] = 0.0
                for i in range(3):
                    row_blocks[e, i, k] = 0.0
                continue
            k_chart_column(Lam_n, xi, r_1, e, k, eps, xa, xb, qa, qb)
            k_cay(xa[0], xa[1], xa[2], Ca)
            k_cay(xb[0], xb[1], xb[2], Cb)
            _k_mm(La0, Ca, La1)
            _k_mm(Lb0, Cb, Lb1)
            if at_levels:  # the row reads level n+1 alone; the level-n force does not depend on u
                _k_constraint_element(h, ds, La1, Lb1, qa, qb, La1, Lb1, qa, qb, lc, ncomp, e1, e2, dl, 0, 0)
                for i in range(12):
                    blocks[e, i, k] = 0.0
            else:
                _k_constraint_element(h, ds, La0, Lb0, ra0, rb0, La1, Lb1, qa, qb, lc, ncomp, e1, e2, dl, 0, 1)
                for i in range(12):
                    col[i] = e1[i].imag * inv
                k_body_rows(Lam_n, e, col, blocks[e, :, k])
            for i in range(3):
                row_blocks[e, i, k] = dl[i].imag * inv
        # lam columns: D1 is linear in lam, so its derivative is D1 at lam = e_i (no perturbation: eps = 0)
        k_chart_column(Lam_n, xi, r_1, e, 0, 0.0, xa, xb, qa, qb)
        k_cay(xa[0], xa[1], xa[2], Ca)
        k_cay(xb[0], xb[1], xb[2], Cb)
        _k_mm(La0, Ca, La1)
        _k_mm(Lb0, Cb, Lb1)
        for j in range(3):
            for i in range(3):
                lc[i] = 1.0 if i == j else 0.0
            if at_levels:  # the force at level n: both "levels" of the kernel at q_n, D1 + D2 the whole gradient
                _k_constraint_element(h, ds, La0, Lb0, ra0, rb0, La0, Lb0, ra0, rb0, lc, ncomp, e1, e2, dl, 0, 2)
                for i in range(12):
                    col[i] = e1[i].real + e2[i].real
            else:
                _k_constraint_element(h, ds, La0, Lb0, ra0, rb0, La1, Lb1, qa, qb, lc, ncomp, e1, e2, dl, 0, 1)
                for i in range(12):
                    col[i] = e1[i].real
            k_body_rows(Lam_n, e, col, lam_blocks[e, :, j])


def constraint_step(h, ds, Lam_n, r_n, Lam_1, r_1, lam, ncomp, levels=(0, 2)):
    """(value, D1 (N+1, 6), D2 (N+1, 6), D_lam (N, 3)) of the constraint term over one step."""
    N = Lam_n.shape[0] - 1
    D1, D2, Dl = np.empty((N + 1, 6)), np.empty((N + 1, 6)), np.empty((N, 3))
    f8 = np.float64
    val = _k_constraint_step(float(h), float(ds), np.ascontiguousarray(Lam_n, dtype=f8), np.ascontiguousarray(r_n, dtype=f8),
                             np.ascontiguousarray(Lam_1, dtype=f8), np.ascontiguousarray(r_1, dtype=f8),
                             np.ascontiguousarray(lam, dtype=f8), int(ncomp), levels[0], levels[1], D1, D2, Dl)
    if levels[0] > 0:
        D1[:] = 0.0
    if levels[1] < 2:
        D2[:] = 0.0
    return val, D1, D2, Dl


def level_constraint_step(h, ds, Lam_n, r_n, Lam_1, r_1, lam, ncomp):
    """The SHAKE form of the constraint (docs/theory.md §9a): the step's term -h ds lam_n . (Gamma(q_n) - chi).

    Returns (value, F (N+1, 6), row (N, 3)): F = its gradient in the level-n variations (dr, sigma) — the
    constraint force, acting at the known level, linear in lam_n — and row = -h ds (Gamma(q_{n+1}) - chi), the
    derivative in lam_{n+1} of the next step's term, which the step solves with q_{n+1} (Gamma = chi at the new
    level).  Both from the midpoint kernel with its two levels at one configuration (its D1 + D2 is then the
    whole gradient, its D_lam the level's strain)."""
    val, D1, D2, _ = constraint_step(h, ds, Lam_n, r_n, Lam_n, r_n, lam, ncomp, (0, 2))
    _, _, _, row = constraint_step(h, ds, Lam_1, r_1, Lam_1, r_1, lam, ncomp, (0, 0))
    return val, D1 + D2, row


def constraint_blocks(h, ds, Lam_n, r_n, xi, r_1, lam, ncomp, mask, eps=1e-30, at_levels=False):
    """The element Newton blocks of :func:`_k_constraint_blocks`: (blocks (N,12,12), lam_blocks (N,12,3),
    row_blocks (N,3,12)); ``at_levels`` for the SHAKE form (:func:`level_constraint_step`)."""
    N = Lam_n.shape[0] - 1
    blocks, lam_blocks, row_blocks = np.empty((N, 12, 12)), np.empty((N, 12, 3)), np.empty((N, 3, 12))
    f8 = np.float64
    _k_constraint_blocks(float(h), float(ds), np.ascontiguousarray(Lam_n, dtype=f8), np.ascontiguousarray(r_n, dtype=f8),
                         np.ascontiguousarray(xi, dtype=f8), np.ascontiguousarray(r_1, dtype=f8),
                         np.ascontiguousarray(lam, dtype=f8), int(ncomp), mask, eps, bool(at_levels), blocks, lam_blocks,
                         row_blocks)
    return blocks, lam_blocks, row_blocks


def element_strain_residual(rod, Lam, r):
    """max |Gamma_e - chi| over the elements at one level (the constraint's monitor; strains of RodPart.strains)."""
    _, Ga = rod.strains(Lam, r)
    return float(np.max(np.abs(Ga - CHI))) if len(Ga) else 0.0


def constraint_jacobian(Lam, r, ds, ncomp, mask):
    """G = d(Gamma_e,i)/d(dr, sigma) at one level, on the unknowns of ``mask`` (nlam x mask.sum(), CSR).

    From the constraint kernel's gradient: at h = 1, lam = e_i on every other element (the elements of one
    parity share no node), D_level = -(ds/2) G^T lam, two parities times ``ncomp`` evaluations.
    """
    import scipy.sparse as sp

    N = Lam.shape[0] - 1
    idx = np.full(mask.shape, -1)
    idx[mask] = np.arange(int(mask.sum()))
    rows, cols, vals = [], [], []
    for parity in (0, 1):
        elems = np.arange(parity, N, 2)
        for i in range(ncomp):
            lam = np.zeros((N, 3))
            lam[elems, i] = 1.0
            _, D, _, _ = constraint_step(1.0, ds, Lam, r, Lam, r, lam, ncomp, (0, 1))
            # D1 at h = 1 with Gamma^n alone varied: value = -ds lam.(Gammabar - chi), dGammabar = dGamma^n / 2
            Gt = -2.0 * D / ds
            for e in elems:
                for node in (e, e + 1):
                    for d in range(6):
                        if mask[node, d] and Gt[node, d] != 0.0:
                            rows.append(e * ncomp + i)
                            cols.append(idx[node, d])
                            vals.append(Gt[node, d])
    return sp.csr_matrix((vals, (rows, cols)), shape=(N * ncomp, int(mask.sum())))


@njit(cache=True)
def _k_constraint_static_blocks(ds, Lam, r, lam, ncomp, mask, eps, blocks):
    """blocks[e, :, k] = d(D1 + D2 of the element at h = 1, both levels at the configuration)/d z_k under
    z = (dr_a, sigma_a, dr_b, sigma_b), Lambda -> Lambda cay(sigma), r -> r + dr (both levels): the derivative
    of the constraint force -ds (dGamma/dq)^T lam, by complex step of its analytic gradient.  Columns off the
    ``mask`` are left zero."""
    N = Lam.shape[0] - 1
    M, V, e1, e2 = _constraint_scratch()
    La, Lb, Lc, C = M[0], M[1], M[2], M[3]
    ra, rb, lc, w, dl = V[0], V[1], V[2], V[3], V[4]
    inv = 1.0 / eps
    for e in range(N):
        for i in range(3):
            lc[i] = lam[e, i]
        for k in range(12):
            if not mask[e + k // 6, k % 6]:
                for i in range(12):
                    blocks[e, i, k] = 0.0
                continue
            _k_config_column(Lam, r, e, k, eps, La, Lb, ra, rb, C, Lc, w)
            _k_constraint_element(1.0, ds, La, Lb, ra, rb, La, Lb, ra, rb, lc, ncomp, e1, e2, dl, 0, 2)
            for i in range(12):
                blocks[e, i, k] = (e1[i].imag + e2[i].imag) * inv


def constraint_static(rod, Lam, r, lam):
    """The constraint at one configuration for statics and modes: ``(c, G, F, H)`` with c = Gamma - chi on the
    constrained components (N*ncomp,), G = dc/dz (N*ncomp x nz, CSR; the rod's unknowns on its mask), the
    constraint force F = -ds G^T lam (nz,) and its derivative H = dF/dz (nz x nz, CSC) — the geometric
    stiffness of the internal forces lam."""
    N, ncomp, mask = rod.N, rod.ncomp, rod.mask
    _, Ga = rod.strains(Lam, r)
    c = (Ga - CHI)[:, :ncomp].ravel()
    G = constraint_jacobian(Lam, r, rod.ds, ncomp, mask)
    _, D1, D2, _ = constraint_step(1.0, rod.ds, Lam, r, Lam, r, lam, ncomp, (0, 2))
    F = (D1 + D2)[mask]
    blocks = np.empty((N, 12, 12))
    _k_constraint_static_blocks(float(rod.ds), np.ascontiguousarray(Lam, dtype=np.float64),
                                np.ascontiguousarray(r, dtype=np.float64), np.ascontiguousarray(lam, dtype=np.float64),
                                int(ncomp), mask, 1e-30, blocks)
    return c, G, F, rod.assemble(blocks)
