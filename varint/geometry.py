"""Parcel volumes of the fluid labels inside a tube of nodal radii.

The radius is interpolated linearly between the lattice nodes,
``R(s) = R_e (1 - t) + R_{e+1} t`` with ``t = (s - e ds)/ds`` on element ``e``,
and the cross-section is the circle ``A = pi R^2``.  Parcel ``k`` occupies
``[s_k, s_{k+1}]``; its volume is integrated exactly,

    V_k = sum_{e0 <= e < e1} Vfull_e + g_{e1}(t1) - g_{e0}(t0),
    g_e(t) = ds pi [a^2 t + a (b - a) t^2 + (b - a)^2 t^3 / 3],  (a, b) = (R_e, R_{e+1}),

so V is C^1 in the label positions (dV/ds_{k+1} = A(R(s_{k+1})) is continuous)
and its second derivative jumps where a label crosses a node (docs/theory.md §3).

Unknowns are addressed in *configuration index space*: label ``k`` is
index ``k`` and node ``j`` is ``n_labels + j``.  Closed tubes have nodes
``0..N``; periodic tubes have ``N`` distinct nodes and node ``N`` is node 0.

The numba kernels are at the bottom; :func:`parcel_volumes_reference` is a
plain quadrature used by the tests to check them.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = [
    "parcel_volumes",
    "parcel_derivatives",
    "parcel_volumes_reference",
    "tube_volume",
    "radius_at",
]


def parcel_volumes(s, R, ds, periodic):
    """Volumes ``V`` (M,) of the parcels between labels ``s`` (M+1,)."""
    V = np.empty(len(s) - 1)
    _volumes(np.ascontiguousarray(s, dtype=np.float64), np.ascontiguousarray(R, dtype=np.float64), ds, periodic, V)
    return V


def parcel_derivatives(s, R, ds, periodic, c1, c2, want_R, want_hessian):
    """Weighted derivatives of the parcel volumes.

    Returns ``(gs, gR, hess, jac)`` where ``gs = sum_k c1_k dV_k/ds``,
    ``gR = sum_k c1_k dV_k/dR``; ``hess`` is a COO triple (rows, cols, vals)
    of ``sum_k c2_k grad V_k grad V_k^T + c1_k hess V_k`` and ``jac`` a COO
    triple of ``dV_k/dq`` (row = parcel k), both in configuration index space.
    With ``want_R`` false the nodal radii are treated as data.
    """
    s = np.ascontiguousarray(s, dtype=np.float64)
    R = np.ascontiguousarray(R, dtype=np.float64)
    return _derivatives(s, R, ds, periodic, np.ascontiguousarray(c1, dtype=np.float64),
                        np.ascontiguousarray(c2, dtype=np.float64), want_R, want_hessian)


def tube_volume(R, ds, periodic):
    """Exact volume of the whole tube and its gradient and (tridiagonal) Hessian in R."""
    a = R if periodic else R[:-1]
    b = np.roll(R, -1) if periodic else R[1:]
    vol = ds * math.pi * np.sum(a * a + a * b + b * b) / 3.0
    grad = np.zeros_like(R)
    ga = ds * math.pi * (2 * a + b) / 3.0
    gb = ds * math.pi * (a + 2 * b) / 3.0
    n = len(R)
    ia = np.arange(len(a))
    ib = (ia + 1) % n
    np.add.at(grad, ia, ga)
    np.add.at(grad, ib, gb)
    c = ds * math.pi / 3.0
    rows = np.concatenate([ia, ib, ia, ib])
    cols = np.concatenate([ia, ib, ib, ia])
    vals = np.concatenate([np.full(len(a), 2 * c), np.full(len(a), 2 * c), np.full(len(a), c), np.full(len(a), c)])
    return vol, grad, (rows, cols, vals)


def radius_at(x, R, ds, periodic):
    """Interpolated radius R(x) at positions x (any shape)."""
    x = np.asarray(x, dtype=np.float64)
    n = len(R)
    if periodic:
        e = np.floor(x / ds)
        t = x / ds - e
        e = e.astype(np.int64) % n
        return R[e] * (1 - t) + R[(e + 1) % n] * t
    e = np.clip(np.floor(x / ds), 0, n - 2).astype(np.int64)
    t = x / ds - e
    return R[e] * (1 - t) + R[e + 1] * t


def parcel_volumes_reference(s, R, ds, periodic):
    """Parcel volumes by adaptive quadrature of pi R(x)^2 (slow, for tests)."""
    from scipy.integrate import quad

    out = []
    for k in range(len(s) - 1):
        lo, hi = float(s[k]), float(s[k + 1])
        # split at nodes so that quad integrates a smooth piece each time
        nodes = np.arange(math.floor(lo / ds) + 1, math.ceil(hi / ds)) * ds
        pts = np.concatenate([[lo], nodes[(nodes > lo) & (nodes < hi)], [hi]])
        v = sum(quad(lambda x: math.pi * float(radius_at(x, R, ds, periodic)) ** 2, a, b, epsabs=0, epsrel=1e-13)[0]
                for a, b in zip(pts[:-1], pts[1:]))
        out.append(v)
    return np.array(out)


# ---------------------------------------------------------------------------
# numba kernels


@njit(cache=True, inline="always")
def _locate(x, ds, nR, periodic):
    """Element index (unwrapped for periodic tubes) and local coordinate t of x."""
    if periodic:
        e = math.floor(x / ds)
    else:
        e = min(max(math.floor(x / ds), 0), nR - 2)
    return e, x / ds - e


@njit(cache=True, inline="always")
def _node(e, nR, periodic):
    return e % nR if periodic else e


@njit(cache=True, inline="always")
def _g(a, b, t, ds):
    d = b - a
    return ds * math.pi * (a * a * t + a * d * t * t + d * d * t * t * t / 3.0)


@njit(cache=True)
def _volumes(s, R, ds, periodic, V):
    nR = R.shape[0]
    for k in range(s.shape[0] - 1):
        e0, t0 = _locate(s[k], ds, nR, periodic)
        e1, t1 = _locate(s[k + 1], ds, nR, periodic)
        v = 0.0
        for e in range(e0, e1):
            a = R[_node(e, nR, periodic)]
            b = R[_node(e + 1, nR, periodic)]
            v += ds * math.pi * (a * a + a * b + b * b) / 3.0
        a1 = R[_node(e1, nR, periodic)]
        b1 = R[_node(e1 + 1, nR, periodic)]
        a0 = R[_node(e0, nR, periodic)]
        b0 = R[_node(e0 + 1, nR, periodic)]
        V[k] = v + _g(a1, b1, t1, ds) - _g(a0, b0, t0, ds)


@njit(cache=True)
def _local_gradient(s, R, ds, periodic, k, e0, t0, e1, t1, g):
    """dV_k/d(local unknowns): g[0] = s_k, g[1] = s_{k+1}, g[2+i] = node e0+i."""
    nR = R.shape[0]
    for i in range(g.shape[0]):
        g[i] = 0.0
    a0 = R[_node(e0, nR, periodic)]
    b0 = R[_node(e0 + 1, nR, periodic)]
    a1 = R[_node(e1, nR, periodic)]
    b1 = R[_node(e1 + 1, nR, periodic)]
    r0 = a0 + (b0 - a0) * t0
    r1 = a1 + (b1 - a1) * t1
    g[0] = -math.pi * r0 * r0
    g[1] = math.pi * r1 * r1
    c = ds * math.pi
    for e in range(e0, e1):
        a = R[_node(e, nR, periodic)]
        b = R[_node(e + 1, nR, periodic)]
        g[2 + e - e0] += c * (2 * a + b) / 3.0
        g[3 + e - e0] += c * (a + 2 * b) / 3.0
    i1 = 2 + e1 - e0
    g[i1] += c * (2 * a1 * t1 + (b1 - 2 * a1) * t1 * t1 - 2 * (b1 - a1) * t1 ** 3 / 3.0)
    g[i1 + 1] += c * (a1 * t1 * t1 + 2 * (b1 - a1) * t1 ** 3 / 3.0)
    g[2] -= c * (2 * a0 * t0 + (b0 - 2 * a0) * t0 * t0 - 2 * (b0 - a0) * t0 ** 3 / 3.0)
    g[3] -= c * (a0 * t0 * t0 + 2 * (b0 - a0) * t0 ** 3 / 3.0)
    return r0, r1, a0, b0, a1, b1


@njit(cache=True)
def _local_hessian(ds, e0, t0, e1, t1, r0, r1, a0, b0, a1, b1, H):
    """Second derivatives of V_k in the local unknowns (same order as the gradient)."""
    n = H.shape[0]
    for i in range(n):
        for j in range(n):
            H[i, j] = 0.0
    H[0, 0] = -2 * math.pi * r0 * (b0 - a0) / ds
    H[1, 1] = 2 * math.pi * r1 * (b1 - a1) / ds
    i1 = 2 + e1 - e0
    # d/ds_{k+1} of A(R(s_{k+1})) w.r.t. the two nodes of element e1, and likewise at s_k
    H[1, i1] += 2 * math.pi * r1 * (1 - t1)
    H[1, i1 + 1] += 2 * math.pi * r1 * t1
    H[0, 2] -= 2 * math.pi * r0 * (1 - t0)
    H[0, 3] -= 2 * math.pi * r0 * t0
    c = ds * math.pi
    for e in range(e0, e1):
        i = 2 + e - e0
        H[i, i] += 2 * c / 3.0
        H[i + 1, i + 1] += 2 * c / 3.0
        H[i, i + 1] += c / 3.0
        H[i + 1, i] += c / 3.0
    for (i, t, sgn) in ((i1, t1, 1.0), (2, t0, -1.0)):
        haa = c * (2 * t - 2 * t * t + 2 * t ** 3 / 3.0)
        hab = c * (t * t - 2 * t ** 3 / 3.0)
        hbb = c * (2 * t ** 3 / 3.0)
        H[i, i] += sgn * haa
        H[i, i + 1] += sgn * hab
        H[i + 1, i] += sgn * hab
        H[i + 1, i + 1] += sgn * hbb
    # the s-R block was filled in rows 0 and 1 only: mirror it
    for j in range(2, n):
        H[j, 0] = H[0, j]
        H[j, 1] = H[1, j]


@njit(cache=True)
def _derivatives(s, R, ds, periodic, c1, c2, want_R, want_hessian):
    nR = R.shape[0]
    nlab = s.shape[0]
    M = nlab - 1
    e0s = np.empty(M, np.int64)
    e1s = np.empty(M, np.int64)
    t0s = np.empty(M)
    t1s = np.empty(M)
    nh = 0
    nj = 0
    nmax = 0
    for k in range(M):
        e0, t0 = _locate(s[k], ds, nR, periodic)
        e1, t1 = _locate(s[k + 1], ds, nR, periodic)
        e0s[k], e1s[k], t0s[k], t1s[k] = e0, e1, t0, t1
        nl = 2 + (e1 - e0 + 2) if want_R else 2
        nh += nl * nl
        nj += nl
        nmax = max(nmax, 2 + e1 - e0 + 2)
    gs = np.zeros(nlab)
    gR = np.zeros(nR)
    if not want_hessian:
        nh = 0
        nj = 0
    rows = np.empty(nh, np.int64)
    cols = np.empty(nh, np.int64)
    vals = np.empty(nh)
    jrows = np.empty(nj, np.int64)
    jcols = np.empty(nj, np.int64)
    jvals = np.empty(nj)
    g = np.empty(nmax)
    H = np.empty((nmax, nmax))
    idx = np.empty(nmax, np.int64)
    ph = 0
    pj = 0
    for k in range(M):
        e0, e1, t0, t1 = e0s[k], e1s[k], t0s[k], t1s[k]
        nfull = 2 + e1 - e0 + 2
        gl = g[:nfull]
        r0, r1, a0, b0, a1, b1 = _local_gradient(s, R, ds, periodic, k, e0, t0, e1, t1, gl)
        idx[0] = k
        idx[1] = k + 1
        for i in range(2, nfull):
            idx[i] = nlab + _node(e0 + i - 2, nR, periodic)
        gs[k] += c1[k] * gl[0]
        gs[k + 1] += c1[k] * gl[1]
        if want_R:
            for i in range(2, nfull):
                gR[idx[i] - nlab] += c1[k] * gl[i]
        if want_hessian:
            nl = nfull if want_R else 2
            Hl = H[:nfull, :nfull]
            _local_hessian(ds, e0, t0, e1, t1, r0, r1, a0, b0, a1, b1, Hl)
            for i in range(nl):
                jrows[pj] = k
                jcols[pj] = idx[i]
                jvals[pj] = gl[i]
                pj += 1
                for j in range(nl):
                    rows[ph] = idx[i]
                    cols[ph] = idx[j]
                    vals[ph] = c2[k] * gl[i] * gl[j] + c1[k] * Hl[i, j]
                    ph += 1
    return gs, gR, (rows, cols, vals), (jrows, jcols, jvals)
