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

Labels must be strictly increasing; a closed tube's labels lie in ``[0, L]`` and a
periodic tube's span one period, ``s_M - s_0 = L``.  :func:`label_problem` names the
first violation; the wrappers check it before calling a kernel and return NaN (no
kernel call) for a configuration outside that domain, so that a Newton iterate which
folds the lattice gives a non-finite residual instead of garbage.  The kernels guard
every index themselves as well (a parcel whose labels are out of order or not finite
gets NaN), so no input can make them read or write outside their arrays.

The numba kernels are at the bottom; :func:`parcel_volumes_reference` is a
plain quadrature used by the tests to check them.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

EPS = np.finfo(float).eps
#: a label farther than this many elements from the origin cannot be located in int64 arithmetic
_MAX_ELEMENTS = 2.0 ** 52

__all__ = [
    "label_problem",
    "parcel_volumes",
    "parcel_derivatives",
    "parcel_volumes_reference",
    "tube_volume",
    "radius_at",
    "k_locate",
    "volume_below",
]


def label_problem(s, nR, ds, periodic, tube=True):
    """The first way labels ``s`` leave the domain of a tube's parcels, or None.

    Returns ``(k, text)``: ``"label k is not finite"``, ``"label k left the tube ..."`` (closed
    tubes: outside ``[0, L]`` beyond round-off), ``"labels out of order at parcel k ..."``
    (``s_{k+1} <= s_k``) or, for a periodic tube, a span ``s_M - s_0`` other than the period.
    ``nR`` is the number of nodal radii (``L = (nR - 1) ds`` closed, ``nR ds`` periodic).
    With ``tube`` false only what the kernels need is checked (finite, increasing labels):
    the volume of a parcel beyond a closed end is still defined (the end element extrapolated),
    which finite differences at the end labels use.
    """
    s = np.asarray(s, dtype=np.float64)
    if s.ndim != 1 or len(s) < 2:
        return 0, f"need at least two labels, got shape {s.shape}"
    L = ds * (nR if periodic else nR - 1)
    # fast path (every residual passes here): increasing labels with valid ends are valid throughout
    # (a NaN anywhere makes the minimum NaN, an infinite label an infinite end or a non-positive difference)
    if np.diff(s).min() > 0:
        if not tube:
            # a periodic span beyond two periods is no lattice state, and the kernels' buffers grow with
            # the number of elements each parcel covers: refuse it rather than allocate without bound
            if math.isfinite(s[0]) and math.isfinite(s[-1]) and (not periodic or s[-1] - s[0] <= 2 * L):
                return None
        elif periodic:
            if abs((s[-1] - s[0]) - L) <= 16 * EPS * max(L, abs(s[0]), abs(s[-1])):
                return None
        elif -8 * EPS * L <= s[0] and s[-1] <= L + 8 * EPS * L:
            return None
    bad = ~np.isfinite(s)
    if bad.any():
        k = int(np.argmax(bad))
        return k, f"label {k} is not finite"
    if tube and not periodic:
        tol = 8 * EPS * L
        out = (s < -tol) | (s > L + tol)
        if out.any():
            k = int(np.argmax(out))
            return k, f"label {k} left the tube (s = {s[k]:.6g} m, tube [0, {L:.6g}] m)"
    d = np.diff(s)
    fold = ~(d > 0)
    if fold.any():
        k = int(np.argmax(fold))
        return k, f"labels out of order at parcel {k} (s_{k} = {s[k]:.9g} m, s_{k + 1} = {s[k + 1]:.9g} m)"
    if not tube and periodic and s[-1] - s[0] > 2 * L:
        return len(s) - 1, f"labels span {s[-1] - s[0]:.6g} m, more than two periods ({2 * L:.6g} m)"
    if tube and periodic:
        span = s[-1] - s[0]
        if abs(span - L) > 16 * EPS * max(L, abs(s[0]), abs(s[-1])):
            return len(s) - 1, f"labels span {span:.17g} m, not the period {L:.17g} m"
    return None


def _valid(s, R, ds, periodic):
    return label_problem(s, len(R), ds, periodic, tube=False) is None


def parcel_volumes(s, R, ds, periodic, check=True):
    """Volumes ``V`` (M,) of the parcels between labels ``s`` (M+1,); NaN if the labels are not finite and increasing.

    ``check=False`` skips that test (for callers that have checked the labels already; the kernel
    itself still gives NaN, never an out-of-bounds access, for a folded parcel).
    """
    s = np.ascontiguousarray(s, dtype=np.float64)
    V = np.empty(len(s) - 1)
    if check and not _valid(s, R, ds, periodic):
        V[:] = np.nan
        return V
    _volumes(s, np.ascontiguousarray(R, dtype=np.float64), ds, periodic, V)
    return V


def parcel_derivatives(s, R, ds, periodic, c1, c2, want_R, want_hessian, check=True):
    """Weighted derivatives of the parcel volumes.

    Returns ``(gs, gR, hess, jac)`` where ``gs = sum_k c1_k dV_k/ds``,
    ``gR = sum_k c1_k dV_k/dR``; ``hess`` is a COO triple (rows, cols, vals)
    of ``sum_k c2_k grad V_k grad V_k^T + c1_k hess V_k`` and ``jac`` a COO
    triple of ``dV_k/dq`` (row = parcel k), both in configuration index space.
    With ``want_R`` false the nodal radii are treated as data.

    Labels that are not finite and increasing (:func:`label_problem` with ``tube=False``) give NaN gradients and NaN on the
    labels' diagonal of ``hess`` and ``jac``, without calling the kernel (``check=False``: as
    :func:`parcel_volumes`).
    """
    s = np.ascontiguousarray(s, dtype=np.float64)
    R = np.ascontiguousarray(R, dtype=np.float64)
    c1 = np.ascontiguousarray(c1, dtype=np.float64)
    c2 = np.ascontiguousarray(c2, dtype=np.float64)
    M = len(s) - 1
    if c1.shape != (M,) or c2.shape != (M,):
        raise ValueError(f"parcel_derivatives: c1 and c2 need shape ({M},), got {c1.shape} and {c2.shape}")
    if check and not _valid(s, R, ds, periodic):
        nan = np.full(len(s), np.nan)
        lab = np.arange(len(s), dtype=np.int64)
        par = np.arange(M, dtype=np.int64)
        if not want_hessian:
            return nan, np.full(len(R), np.nan), _empty_coo(), _empty_coo()
        return nan, np.full(len(R), np.nan), (lab, lab, nan.copy()), (par, par, np.full(M, np.nan))
    return _derivatives(s, R, ds, periodic, c1, c2, want_R, want_hessian)


def _empty_coo():
    return np.empty(0, np.int64), np.empty(0, np.int64), np.empty(0)


def tube_volume(R, ds, periodic):
    """Exact volume of the whole tube and its gradient and (tridiagonal) Hessian in R."""
    a = R if periodic else R[:-1]
    b = np.roll(R, -1) if periodic else R[1:]
    vol = float(np.sum(_full(a, b, ds)))  # the kernels' whole element, on the arrays
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
def k_locate(x, ds, nR, periodic):
    """Element index (unwrapped for periodic tubes), local coordinate t of x, and whether x can be located.

    A closed tube's index is clamped to its elements (labels beyond the ends extrapolate the
    end element); a non-finite or astronomically far x gets element 0 and ``False``.
    """
    u = x / ds
    if not (abs(u) < _MAX_ELEMENTS):
        return 0, 0.0, False
    e = math.floor(u)
    if not periodic:
        e = min(max(e, 0), nR - 2)
    return e, u - e, True


@njit(cache=True, inline="always")
def _parcel_ok(x0, x1, e0, e1, ok0, ok1, nR, periodic):
    """A parcel the kernels can integrate: located labels in order, spanning at most one period."""
    if not (ok0 and ok1 and x1 >= x0 and e1 >= e0):
        return False
    return not (periodic and e1 - e0 > nR)


@njit(cache=True)
def _check_shapes(nlab, nR, periodic, ds):
    if nR < (1 if periodic else 2):
        raise ValueError("parcel kernels: too few nodal radii")
    if nlab < 1:
        raise ValueError("parcel kernels: no labels")
    if not (ds > 0.0):
        raise ValueError("parcel kernels: ds must be positive")


@njit(cache=True, inline="always")
def _node(e, nR, periodic):
    return e % nR if periodic else e


@njit(cache=True, inline="always")
def _g(a, b, t, ds):
    """int_0^t pi R^2 ds on an element of end radii a, b (R linear), to local coordinate t: the element integral."""
    d = b - a
    return ds * math.pi * (a * a * t + a * d * t * t + d * d * t * t * t / 3.0)


@njit(cache=True, inline="always")
def _full(a, b, ds):
    """The whole element's volume, :func:`_g` at t = 1 written without cancellation."""
    return ds * math.pi * (a * a + a * b + b * b) / 3.0


@njit(cache=True)
def _k_volume_below(x, R, ds, out):
    """out[k] = int_0^x_k pi R^2 ds on a closed tube (the end elements extrapolated beyond its ends; NaN where x_k
    cannot be located)."""
    nR = R.shape[0]
    F = np.zeros(nR)
    for e in range(nR - 1):
        F[e + 1] = F[e] + _full(R[e], R[e + 1], ds)
    for k in range(x.shape[0]):
        e, t, ok = k_locate(x[k], ds, nR, False)
        out[k] = F[e] + _g(R[e], R[e + 1], t, ds) if ok else np.nan


def volume_below(x, R, ds):
    """F(x) = int_0^x pi R(s)^2 ds on a closed tube of nodal radii R, at positions x (any shape; beyond the ends the
    end elements are extrapolated): the parcel kernels' element integrals, so F(s_{k+1}) - F(s_k) is V_k."""
    x = np.asarray(x, dtype=np.float64)
    out = np.empty(x.size)
    _k_volume_below(np.ascontiguousarray(x.ravel()), np.ascontiguousarray(R, dtype=np.float64), float(ds), out)
    return out.reshape(x.shape)


@njit(cache=True)
def _volumes(s, R, ds, periodic, V):
    nR = R.shape[0]
    _check_shapes(s.shape[0], nR, periodic, ds)
    if V.shape[0] < s.shape[0] - 1:
        raise ValueError("parcel kernels: V is shorter than the number of parcels")
    e1, t1, ok1 = k_locate(s[0], ds, nR, periodic)
    for k in range(s.shape[0] - 1):
        e0, t0, ok0 = e1, t1, ok1  # each label is located once
        e1, t1, ok1 = k_locate(s[k + 1], ds, nR, periodic)
        if not _parcel_ok(s[k], s[k + 1], e0, e1, ok0, ok1, nR, periodic):
            V[k] = np.nan
            continue
        v = 0.0
        for e in range(e0, e1):
            v += _full(R[_node(e, nR, periodic)], R[_node(e + 1, nR, periodic)], ds)
        a1 = R[_node(e1, nR, periodic)]
        b1 = R[_node(e1 + 1, nR, periodic)]
        a0 = R[_node(e0, nR, periodic)]
        b0 = R[_node(e0 + 1, nR, periodic)]
        V[k] = v + _g(a1, b1, t1, ds) - _g(a0, b0, t0, ds)


@njit(cache=True)
def k_parcel_gradient(s, R, ds, periodic, k, e0, t0, e1, t1, g):
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
def k_parcel_hessian(ds, e0, t0, e1, t1, r0, r1, a0, b0, a1, b1, H):
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
    _check_shapes(nlab, nR, periodic, ds)
    M = nlab - 1
    if c1.shape[0] < M or c2.shape[0] < M:
        raise ValueError("parcel kernels: c1 or c2 is shorter than the number of parcels")
    e0s = np.empty(M, np.int64)
    e1s = np.empty(M, np.int64)
    t0s = np.empty(M)
    t1s = np.empty(M)
    ok = np.empty(M, np.bool_)
    nh = 0
    nj = 0
    nmax = 4
    ea, ta, oka = k_locate(s[0], ds, nR, periodic)
    for k in range(M):
        e0, t0, ok0 = ea, ta, oka  # each label is located once
        e1, t1, ok1 = k_locate(s[k + 1], ds, nR, periodic)
        ea, ta, oka = e1, t1, ok1
        ok[k] = _parcel_ok(s[k], s[k + 1], e0, e1, ok0, ok1, nR, periodic)
        if not ok[k]:  # a NaN block on one element keeps every index in range
            e1 = e0
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
        if ok[k]:
            r0, r1, a0, b0, a1, b1 = k_parcel_gradient(s, R, ds, periodic, k, e0, t0, e1, t1, gl)
        else:
            gl[:] = np.nan
            r0 = r1 = a0 = b0 = a1 = b1 = np.nan
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
            Hl = H[:nfull, :nfull]
            if ok[k]:
                k_parcel_hessian(ds, e0, t0, e1, t1, r0, r1, a0, b0, a1, b1, Hl)
            else:
                Hl[:, :] = np.nan
            nl = nfull if want_R else 2
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
