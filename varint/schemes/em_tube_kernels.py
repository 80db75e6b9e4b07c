"""Compiled per-pair loops of the coupled energy-momentum step's fluid terms (varint/schemes/em_tube.py, docs/theory.md §12b).

:meth:`varint.schemes.em_tube.TubeEMStep.fluid_discrete_gradient` works on (parcel, element) pairs: the parcel volumes at the
new level and the discrete gradient of sum_k c_k V_k in the labels s, the radii R and the nodal stretches gamma.  In
numpy these are ~40 array operations on arrays of a few dozen pairs, and at the sizes the step is used at their call
overhead is most of a chord iteration.  These kernels are the same arithmetic as one loop over the pairs, on a batch
of levels (rows), real (the chord iterations) or complex (the complex-step Jacobian's batches: comparisons read real
parts, as numpy's).  The numpy code stays the readable reference; tests/test_tube_em.py checks the two against each
other.

Notation as in tube_em: pair p covers parcel k = pk[p] on element e = pe[p]; the label coordinates on the element
t = s/ds - e; M_q(t) = int_0^t (1 - tau)^(3 - q) tau^q dtau (varint.lattice.centreline.MQ); S_q = M_q(t_hi) - M_q(t_lo);
the pair's volume ds pi sum_(ijl) R_i R_j gamma_l S_(i+j+l) over its element's two end nodes i, j, l in {0, 1}.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..lattice.centreline import k_cr_dd, k_cr_stencil, k_cr_weights, k_fold_ghost, k_moments, k_moments_dd, k_piece_volume


@njit(cache=True)
def _clip01(t):
    """t clipped to [0, 1] by its real part (a complex step passes through inside)."""
    return 0.0 if t.real < 0.0 else (1.0 if t.real > 1.0 else t)


@njit(cache=True)
def _clip_owned(t, last):
    """t clipped to [0, 1] by its real part; at t = 1 a complex step passes only on the last element (the next
    element owns a label on a node: tube_em._clip_owned)."""
    re = t.real
    if re < 0.0:
        return 0.0 * t
    if re > 1.0 or (re == 1.0 and not last):
        return 1.0 + 0.0 * t
    return t


@njit(cache=True)
def _moments(t, last, out):
    """out[q] = M_q(clip t), q = 0..3 (tube_em._moments; varint.lattice.centreline.k_moments)."""
    k_moments(_clip_owned(t, last), out)


@njit(cache=True)
def _moment_dd(t0, t1, last, out):
    """out[q] = (M_q(clip t1) - M_q(clip t0))/(t1 - t0), cancellation-free (tube_em._moment_dd): the polynomials'
    divided difference between the clipped ends (varint.lattice.centreline.k_moments_dd) times the fraction of
    [t0, t1] inside [0, 1]; where t0 = t1 (real parts) the derivative on the element that owns the point ([0, 1), or
    [0, 1] on the last element)."""
    a, b = _clip01(t0), _clip01(t1)
    dt = t1 - t0
    if dt.real == 0.0:
        re = t0.real
        frac = (1.0 + 0.0 * dt) if (re >= 0.0 and (re < 1.0 or (last and re <= 1.0))) else 0.0 * dt
    else:
        frac = (b - a) / dt
    k_moments_dd(a, b, out)
    for q in range(4):
        out[q] *= frac


@njit(cache=True)
def pair_volumes(s, R, gam, pk, pe, ds, out):
    """out (B, M) = parcel volumes V_k of the levels (rows of s (B, M+1), R, gam (B, N+1)): the pairs' volumes
    (varint.lattice.centreline.k_piece_volume) summed into their parcels (tube_em's _volumes_on)."""
    Sh = np.empty(4, dtype=out.dtype)
    Sl = np.empty(4, dtype=out.dtype)
    out[:] = 0.0
    for b in range(s.shape[0]):
        for p in range(pk.size):
            k, e = pk[p], pe[p]
            last = e == R.shape[1] - 2
            _moments(s[b, k + 1] / ds - e, last, Sh)
            _moments(s[b, k] / ds - e, last, Sl)
            for q in range(4):
                Sh[q] -= Sl[q]
            out[b, k] += k_piece_volume(R[b, e], R[b, e + 1], gam[b, e], gam[b, e + 1], Sh, ds)


@njit(cache=True)
def pair_gradients(s0, s1, R0, R1, g0, g1, pk, pe, c, S0, ds, gs, gR, gg):
    """The discrete gradient of sum_k c_k V_k between the level (s0, R0, g0: real, 1-D; S0 (npairs, 4) its pairs'
    S_q, as tube_em's level cache keeps them) and each row of (s1, R1, g1) with its coefficients c (B, M), per pair
    and scattered: gs (B, M+1) on all labels, gR (B, N+1) on the radii,
    gg (B, N+1) on the nodal stretches (tube_em.TubeEMStep.fluid_discrete_gradient's numpy path)."""
    N = R0.size - 1
    dt = gs.dtype
    S1h, S1l = np.empty(4, dtype=dt), np.empty(4, dtype=dt)
    ddh, ddl, Sb = np.empty(4, dtype=dt), np.empty(4, dtype=dt), np.empty(4, dtype=dt)
    gR_p, gG_p = np.empty(2, dtype=dt), np.empty(2, dtype=dt)
    gs[:] = 0.0
    gR[:] = 0.0
    gg[:] = 0.0
    for b in range(s1.shape[0]):
        for p in range(pk.size):
            k, e = pk[p], pe[p]
            last = e == N - 1
            tl0, th0 = s0[k] / ds - e, s0[k + 1] / ds - e
            tl1, th1 = s1[b, k] / ds - e, s1[b, k + 1] / ds - e
            _moments(th1, last, S1h)
            _moments(tl1, last, S1l)
            for q in range(4):
                Sb[q] = 0.5 * (S0[p, q] + (S1h[q] - S1l[q]))
            _moment_dd(th0 + 0.0 * th1, th1, last, ddh)
            _moment_dd(tl0 + 0.0 * tl1, tl1, last, ddl)
            g_hi = 0.0 * Sb[0]
            g_lo = 0.0 * Sb[0]
            gR_p[:] = 0.0
            gG_p[:] = 0.0
            for i in range(2):
                for j in range(2):
                    # the AVF weight of R_i R_j (both linear between the levels)
                    rr = ((R0[e + i] * R0[e + j] + R1[b, e + i] * R1[b, e + j]) / 3.0
                          + (R0[e + i] * R1[b, e + j] + R1[b, e + i] * R0[e + j]) / 6.0)
                    for l in range(2):
                        q = i + j + l
                        Pb = 0.5 * (R0[e + i] * R0[e + j] * g0[e + l] + R1[b, e + i] * R1[b, e + j] * g1[b, e + l])
                        g_hi += Pb * ddh[q]
                        g_lo -= Pb * ddl[q]
                        # Delta P = Delta R_i avf(R_j, g_l) + Delta R_j avf(R_i, g_l) + ... (S_q symmetric in i, j)
                        rg = ((R0[e + j] * g0[e + l] + R1[b, e + j] * g1[b, e + l]) / 3.0
                              + (R0[e + j] * g1[b, e + l] + R1[b, e + j] * g0[e + l]) / 6.0)
                        gR_p[i] += 2.0 * Sb[q] * rg
                        gG_p[l] += Sb[q] * rr
            kk = np.pi * c[b, k]
            gs[b, k] += kk * g_lo
            gs[b, k + 1] += kk * g_hi
            gR[b, e] += ds * kk * gR_p[0]
            gR[b, e + 1] += ds * kk * gR_p[1]
            gg[b, e] += ds * kk * gG_p[0]
            gg[b, e + 1] += ds * kk * gG_p[1]


# -- the labels' constraint c_k = D_e^T (X_k - X(s_k)) and its discrete derivative's forces (tube_em.label_constraint)
# The Catmull-Rom weights of a label on element e (nodes e-1..e+2, the closed ends' ghosts folded into the real nodes:
# varint.lattice.centreline's k_cr_weights, k_cr_stencil, k_fold_ghost; docs/theory.md §10.2).


@njit(cache=True)
def _element(s_re, ds, n_el):
    e = int(np.floor(s_re / ds))
    return 0 if e < 0 else (n_el - 1 if e > n_el - 1 else e)


@njit(cache=True, inline="always")
def _add_piece(row, e, n_nodes, coef, w, nodes):
    """row[node] += coef w[i] over element e's stencil (w: weights of nodes e-1..e+2), its ghost folded."""
    k_fold_ghost(k_cr_stencil(e, n_nodes, False, nodes), w)
    for i in range(4):
        row[nodes[i]] += coef * w[i]


@njit(cache=True)
def _dd_row(s0, s1, ds, n_el, row, w, nodes):
    """The label's divided differences (N_i(s1) - N_i(s0))/(s1 - s0) on the nodes, into ``row`` (zero on entry);
    returns the range (lo, hi) of nodes written.  Per element crossed, the polynomial divided difference between the
    piece's ends (varint.lattice.centreline.k_cr_dd) times its share of the step (tube_em.label_weights_dd)."""
    n_nodes = n_el + 1
    e0 = _element(s0, ds, n_el)
    e1 = _element(s1.real, ds, n_el)
    a = s0 / ds - e0
    if e0 == e1:
        k_cr_dd(a + 0.0 * s1, s1 / ds - e0, w)
        _add_piece(row, e0, n_nodes, 1.0 / ds, w, nodes)
        return max(e0 - 1, 0), min(e0 + 2, n_el)
    up = e1 > e0
    dsv = s1 - s0
    b = 1.0 if up else 0.0
    k_cr_dd(a + 0.0 * s1, b + 0.0 * s1, w)
    _add_piece(row, e0, n_nodes, (b - a) / dsv, w, nodes)
    a = 0.0 if up else 1.0
    b1 = s1 / ds - e1
    k_cr_dd(a + 0.0 * s1, b1, w)
    _add_piece(row, e1, n_nodes, (b1 - a) / dsv, w, nodes)
    sign = 1.0 if up else -1.0
    lo_e, hi_e = (e0, e1) if up else (e1, e0)
    for e in range(lo_e + 1, hi_e):  # whole elements crossed in one step (rare)
        lo, hi = (0.0, 1.0) if up else (1.0, 0.0)
        k_cr_dd(lo + 0.0 * s1, hi + 0.0 * s1, w)
        _add_piece(row, e, n_nodes, sign / dsv, w, nodes)
    return max(lo_e - 1, 0), min(hi_e + 2, n_el)


@njit(cache=True)
def label_constraint(r0, D0, X0, s0, fr, r1, D1, s1, X1, nu, ds, c1, Fr, FD, Fs, FX):
    """The labels' constraint at the new levels and its discrete derivative's forces from the multipliers nu, for each
    row b of the batch (r1 (B, N+1, 3), D1 (B, N+1, 3, 3), s1 (B, M+1), X1, nu (B, M-1, 3)); the level (r0, D0, X0,
    s0) real, fr the labels' frame nodes.  Writes c1 (B, M-1, 3), Fr (B, N+1, 3), FD (B, N+1, 3, 3), Fs (B, M-1),
    FX (B, M-1, 3): tube_em.TubeEMStep.label_constraint's numpy path."""
    N = r0.shape[0] - 1
    K = X0.shape[0]
    dt = c1.dtype
    w0, w1, w = np.empty(4), np.empty(4, dtype=dt), np.empty(4, dtype=dt)
    n0, n1, nodes = np.empty(4, np.int64), np.empty(4, np.int64), np.empty(4, np.int64)
    row = np.zeros(N + 1, dtype=dt)
    x1, xb, Dnu, y0, y1, nu_b = (np.empty(3, dtype=dt), np.empty(3, dtype=dt), np.empty(3, dtype=dt),
                                 np.empty(3, dtype=dt), np.empty(3, dtype=dt), np.empty(3, dtype=dt))
    Fr[:] = 0.0
    FD[:] = 0.0
    for b in range(r1.shape[0]):
        for k in range(K):
            j = fr[k]
            sk0, sk1 = s0[k + 1], s1[b, k + 1]
            e0 = _element(sk0, ds, N)
            e1 = _element(sk1.real, ds, N)
            k_cr_weights(sk0 / ds - e0, w0)
            k_fold_ghost(k_cr_stencil(e0, N + 1, False, n0), w0)
            k_cr_weights(sk1 / ds - e1, w1)
            k_fold_ghost(k_cr_stencil(e1, N + 1, False, n1), w1)
            # x1 = X1 - X(s1) at level 1; xb = Xbar - Wbar rbar (Wbar, rbar the levels' means)
            for a in range(3):
                X1a = X1[b, k, a]
                g1 = 0.0 * X1a
                gb = 0.0 * X1a
                for i in range(4):
                    p1 = r1[b, n1[i], a]
                    g1 += w1[i] * p1
                    gb += 0.25 * w1[i] * (r0[n1[i], a] + p1)
                    gb += 0.25 * w0[i] * (r0[n0[i], a] + r1[b, n0[i], a])
                x1[a] = X1a - g1
                xb[a] = 0.5 * (X0[k, a] + X1a) - gb
            for a in range(3):
                acc = 0.0 * x1[0]
                for i in range(3):
                    acc += D1[b, j, i, a] * x1[i]
                c1[b, k, a] = acc
                nu_b[a] = nu[b, k, a]
            for a in range(3):
                acc = 0.0 * x1[0]
                for i in range(3):
                    acc += 0.5 * (D0[j, a, i] + D1[b, j, a, i]) * nu_b[i]
                Dnu[a] = acc
                FX[b, k, a] = acc
            for i in range(4):
                for a in range(3):
                    Fr[b, n0[i], a] += -0.5 * w0[i] * Dnu[a]
                    Fr[b, n1[i], a] += -0.5 * w1[i] * Dnu[a]
            for a in range(3):
                for i in range(3):
                    FD[b, j, a, i] += xb[a] * nu_b[i]
            # F_s = -(1/2) sum_l (DD r_l) . (D_e^l nu), l = 0, 1
            lo, hi = _dd_row(sk0, sk1, ds, N, row, w, nodes)
            for a in range(3):
                acc0 = 0.0 * x1[0]
                acc1 = 0.0 * x1[0]
                for q in range(lo, hi + 1):
                    acc0 += row[q] * r0[q, a]
                    acc1 += row[q] * r1[b, q, a]
                y0[a] = acc0
                y1[a] = acc1
            for q in range(lo, hi + 1):
                row[q] = 0.0
            acc = 0.0 * x1[0]
            for a in range(3):
                for i in range(3):
                    acc += y0[a] * D0[j, a, i] * nu_b[i] + y1[a] * D1[b, j, a, i] * nu_b[i]
            Fs[b, k] = -0.5 * acc
