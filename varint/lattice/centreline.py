"""Geometry of the coupled tube (docs/theory.md §10.2, §10.3): element-local kernels, exact derivatives.

Two pieces of the coupled tube's discrete Lagrangian that do not depend on how the model is assembled:

* **Labels on the moving centreline** (§10.2): X(s; r) = sum_i N_i(t) r_i, the Catmull–Rom
  (cubic Hermite) interpolant of the nodal positions, with nodal tangents (r_{j+1} - r_{j-1})/(2 ds)
  and quadratic-extrapolation ghosts at closed ends.  Its weights sum to one (so X moves with any
  rigid motion of the nodes), it passes through the nodes and X' is continuous at them.
  :func:`centreline_weights` returns, for labels s, the four nodes each reads and the weights
  N_i, N_i' = dN_i/ds and N_i'' = d^2 N_i/ds^2; X, X', X'' and every derivative of a term in X with
  respect to r follow from them (X is linear in r).

* **Parcel volumes with a stretch** (§10.3): V_k = int_{s_k}^{s_{k+1}} pi R(s)^2 gamma(s) ds with R
  and the nodal stretch gamma (gamma_j = mean |Gamma| of the elements at node j) both linear between
  nodes.  On an element with hat functions phi_0 = 1 - t, phi_1 = t the integrand is the cubic form
  sum_{i,j,l} R_i R_j gamma_l phi_i phi_j phi_l, so

      G_e(t) = ds pi sum_{i,j,l in {0,1}} R_i R_j gamma_l M_{i+j+l}(t),
      M_q(t) = int_0^t (1 - tau)^(3-q) tau^q dtau,

  and V_k = sum of G_e(1) over the elements a parcel covers plus G_e1(t1) - G_e0(t0).  Every first
  and second derivative in (s, R, gamma) is then a contraction of the same moments: exact, with no
  case analysis.  With gamma = 1 the volumes are those of :mod:`varint.lattice.parcels` (tested equal).

The one-model rewrite (docs/theory.md §10) assembles these into the coupled terms; until then they are
tested against independent references (quadrature, finite differences) in tests/test_coupled_geometry.py.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .parcels import k_locate, label_problem

EPS = np.finfo(float).eps

__all__ = ["centreline_weights", "centreline", "centreline_and_weights", "stretched_volumes", "stretched_volume_derivatives",
           "nodal_stretch", "CR", "GHOST", "MQ"]


# ---------------------------------------------------------------------------
# Catmull–Rom centreline


def centreline_weights(s, n_nodes, ds, periodic=False):
    """Nodes and weights of X(s) = sum_i N_i r_i for labels ``s``.

    Returns ``(nodes, N, dN, d2N)``, each of shape (len(s), 4) (``nodes`` int): node indices (mod
    ``n_nodes`` for a periodic tube, whose period shift the caller adds), the weights, and their first
    and second derivatives with respect to s.  Closed ends fold the ghost nodes r_{-1} = 3r_0 - 3r_1 + r_2
    and r_{N+1} = 3r_N - 3r_{N-1} + r_{N-2} into the real ones, so a node may appear twice in a row with
    the weights split between the entries (sums over entries are what count).
    """
    s = np.ascontiguousarray(s, dtype=np.float64)
    bad = ~np.isfinite(s)
    if not periodic:
        L = (n_nodes - 1) * ds
        bad |= (s < -8 * EPS * L) | (s > L * (1 + 8 * EPS))
    if bad.any():
        k = int(np.argmax(bad))
        raise ValueError(f"label {k} (s = {s[k]:.6g} m) is not on the centreline")
    if not periodic and n_nodes < 3:
        raise ValueError("a closed centreline needs at least 3 nodes (quadratic end extrapolation)")
    nodes = np.empty((len(s), 4), np.int64)
    N = np.empty((len(s), 4))
    dN = np.empty((len(s), 4))
    d2N = np.empty((len(s), 4))
    k_centreline_weights(s, n_nodes, ds, periodic, nodes, N, dN, d2N)
    return nodes, N, dN, d2N


def centreline(s, r, ds, periodic=False, period=None):
    """X(s), X'(s), X''(s) for labels ``s`` on nodal positions ``r`` (n_nodes, 3).

    ``period``: the shift vector d with r_{j+N} = r_j + d for a periodic tube (default L e_1).
    """
    return centreline_and_weights(s, r, ds, periodic, period)[3:]


def centreline_and_weights(s, r, ds, periodic=False, period=None):
    """``(nodes, N, dN, X, X', X'')``: :func:`centreline_weights` and the centreline they give."""
    r = np.asarray(r, dtype=np.float64)
    nodes, N, dN, d2N = centreline_weights(s, len(r), ds, periodic)
    pts = r[nodes]
    if periodic:
        d = np.array([len(r) * ds, 0.0, 0.0]) if period is None else np.asarray(period, dtype=np.float64)
        e = np.floor(np.asarray(s) / ds).astype(np.int64)
        unwrapped = e[:, None] + np.arange(-1, 3)[None, :]
        pts = pts + np.floor_divide(unwrapped, len(r))[:, :, None] * d
    return (nodes, N, dN, np.einsum("ki,kid->kd", N, pts), np.einsum("ki,kid->kd", dN, pts),
            np.einsum("ki,kid->kd", d2N, pts))


#: the Catmull-Rom weights of nodes e-1, e, e+1, e+2 at the local coordinate t of element e, as coefficients of
#: t^0..t^3 (row i: node e-1+i; docs/theory.md §10.2): the one definition of the basis; its derivatives and divided
#: differences are those of these polynomials (:func:`k_cr_basis`, :func:`k_cr_dd`)
CR = 0.5 * np.array([[0.0, -1.0, 2.0, -1.0],
                     [2.0, 0.0, -5.0, 3.0],
                     [0.0, 1.0, 4.0, -3.0],
                     [0.0, 0.0, -1.0, 1.0]])
#: a closed end's ghost node by quadratic extrapolation: r_{-1} = 3 r_0 - 3 r_1 + r_2, r_{N+1} = 3 r_N - 3 r_{N-1} +
#: r_{N-2} (the coefficients of the end node, its neighbour and the next)
GHOST = np.array([3.0, -3.0, 1.0])


@njit(cache=True, inline="always")
def k_cr_weights(t, w):
    """w[i] = the Catmull-Rom weight of node e-1+i at local coordinate t (any scalar type)."""
    t2 = t * t
    t3 = t2 * t
    for i in range(4):
        w[i] = CR[i, 0] + CR[i, 1] * t + CR[i, 2] * t2 + CR[i, 3] * t3


@njit(cache=True, inline="always")
def k_cr_basis(t, w, dw, d2w):
    """The Catmull-Rom weights of nodes e-1..e+2 at local coordinate t (:func:`k_cr_weights`) and their first
    (:func:`k_cr_dd` at equal ends) and second t-derivatives."""
    k_cr_weights(t, w)
    k_cr_dd(t, t, dw)
    for i in range(4):
        d2w[i] = 2.0 * CR[i, 2] + 6.0 * CR[i, 3] * t


@njit(cache=True, inline="always")
def k_cr_dd(a, b, w):
    """w[i] = (N_i(b) - N_i(a)) / (b - a) in local coordinates, exact for a = b too (the derivative) and free of
    cancellation: the polynomials' divided differences, (b^p - a^p)/(b - a) = sum_q a^q b^(p-1-q)."""
    d2 = a + b
    d3 = a * a + a * b + b * b
    for i in range(4):
        w[i] = CR[i, 1] + CR[i, 2] * d2 + CR[i, 3] * d3


@njit(cache=True, inline="always")
def k_cr_stencil(e, n_nodes, periodic, nodes):
    """Nodes e-1..e+2 of element e's Catmull-Rom stencil into ``nodes`` (mod n_nodes when periodic); returns the slot
    of a closed end's ghost (0: node -1, 3: node N+1), or -1.  :func:`k_fold_ghost` folds its weight."""
    for i in range(4):
        j = e - 1 + i
        nodes[i] = j % n_nodes if periodic else j
    if periodic:
        return -1
    if nodes[0] < 0:
        nodes[0] = 2  # its weight stays on r_2 (GHOST[2]), the rest goes to nodes 0 and 1 (slots 1, 2)
        return 0
    if nodes[3] > n_nodes - 1:
        nodes[3] = n_nodes - 3  # on r_{N-2}, the rest on nodes N and N-1 (slots 2, 1)
        return 3
    return -1


@njit(cache=True, inline="always")
def k_fold_ghost(slot, w):
    """A closed end's ghost (:data:`GHOST`) in stencil ``slot`` (:func:`k_cr_stencil`) folded into the weights w (4,)
    of the real nodes: the end node's and its neighbour's slots gain 3 w and -3 w; the slot keeps w for the third
    node.  A node may then appear twice in the stencil (sums over entries are what count)."""
    if slot < 0:
        return
    x = w[slot]
    end, nbr = (1, 2) if slot == 0 else (2, 1)
    w[end] += GHOST[0] * x
    w[nbr] += GHOST[1] * x
    w[slot] = GHOST[2] * x


@njit(cache=True, inline="always")
def k_stencil_point(r, node, e, i, n_nodes, periodic, period, d):
    """Component d of the position of entry i of element e's stencil (its node ``node``): r_node, and on a periodic
    tube the period (3,) times the wraps of the unwrapped node e - 1 + i (r_{j+N} = r_j + period)."""
    if periodic:
        return r[node, d] + ((e - 1 + i) // n_nodes) * period[d]
    return r[node, d]


@njit(cache=True)
def k_centreline_weights(s, n_nodes, ds, periodic, nodes, N, dN, d2N):
    n_el = n_nodes if periodic else n_nodes - 1
    for k in range(s.shape[0]):
        e = int(math.floor(s[k] / ds))
        if not periodic:
            e = min(max(e, 0), n_el - 1)  # the closed end s = L belongs to the last element
        t = s[k] / ds - e
        k_cr_basis(t, N[k], dN[k], d2N[k])
        for i in range(4):
            dN[k, i] /= ds
            d2N[k, i] /= ds * ds
        ghost = k_cr_stencil(e, n_nodes, periodic, nodes[k])
        k_fold_ghost(ghost, N[k])
        k_fold_ghost(ghost, dN[k])
        k_fold_ghost(ghost, d2N[k])


# ---------------------------------------------------------------------------
# parcel volumes with a nodal stretch


def nodal_stretch(stretch_elements, periodic=False):
    """gamma_j from element stretches |Gamma_e| (..., n_el): the mean of the elements at node j (§10.3), a closed
    end node taking its one element's (leading batch axes, real or complex; the compiled kernels' entries:
    :func:`k_stretch_weight`)."""
    g = np.asarray(stretch_elements)
    if not np.iscomplexobj(g):
        g = g.astype(np.float64, copy=False)
    if periodic:
        return 0.5 * (g + np.roll(g, 1, axis=-1))
    return np.concatenate([g[..., :1], 0.5 * (g[..., :-1] + g[..., 1:]), g[..., -1:]], -1)


@njit(cache=True, inline="always")
def k_stretch_weight(j, n_nodes, periodic):
    """T_je for j an end node of element e: the element's share of the nodal stretch gamma_j (:func:`nodal_stretch`):
    1/2, but 1 at a closed tube's end nodes, which have one element only."""
    if not periodic and (j == 0 or j == n_nodes - 1):
        return 1.0
    return 0.5


def _prepare(s, R, gamma, ds, periodic):
    s = np.ascontiguousarray(s, dtype=np.float64)
    R = np.ascontiguousarray(R, dtype=np.float64)
    gamma = np.ascontiguousarray(gamma, dtype=np.float64)
    if R.shape != gamma.shape:
        raise ValueError(f"R and gamma need the same shape, got {R.shape} and {gamma.shape}")
    problem = label_problem(s, len(R), ds, periodic, tube=False)
    if problem is not None:
        raise ValueError(problem[1])
    return s, R, gamma


def stretched_volumes(s, R, gamma, ds, periodic=False):
    """V_k = int pi R^2 gamma ds over each parcel [s_k, s_{k+1}], exactly."""
    s, R, gamma = _prepare(s, R, gamma, ds, periodic)
    V = np.empty(len(s) - 1)
    _k_stretched_volumes(s, R, gamma, ds, periodic, V)
    return V


def stretched_volume_derivatives(s, R, gamma, ds, periodic=False):
    """Exact derivatives of every V_k in its local unknowns.

    Returns ``(V, index, grad, hess)``: ``index`` (M, n_loc) lists the configuration indices of
    parcel k's local unknowns — label k, label k+1, then the radii and then the stretches of the nodes
    e0..e0+n-1 it touches, as ``("s", k)``-free integers: labels 0..M, radii M+1+j, stretches
    M+1+nR+j (-1 pads unused slots); ``grad`` (M, n_loc) and ``hess`` (M, n_loc, n_loc) the first and
    second derivatives in that order.  Every parcel has the same n_loc = 2 + 2 (span + 2), span the
    largest number of elements a parcel reaches into.
    """
    s, R, gamma = _prepare(s, R, gamma, ds, periodic)
    nR = len(R)
    e0 = np.floor(s[:-1] / ds).astype(np.int64)
    e1 = np.floor(s[1:] / ds).astype(np.int64)
    if not periodic:
        e0 = np.clip(e0, 0, nR - 2)
        e1 = np.clip(e1, 0, nR - 2)
    span = int(np.max(e1 - e0)) + 1 if len(s) > 1 else 1
    n_nodes = span + 1
    n_loc = 2 + 2 * n_nodes
    M = len(s) - 1
    V = np.empty(M)
    index = np.full((M, n_loc), -1, np.int64)
    grad = np.zeros((M, n_loc))
    hess = np.zeros((M, n_loc, n_loc))
    k_stretched_derivatives(s, R, gamma, ds, periodic, n_nodes, V, index, grad, hess)
    return V, index, grad, hess


#: M_q(t) = int_0^t (1 - tau)^(3 - q) tau^q dtau, q = 0..3, as coefficients of t^1..t^4 (row q): the element's moments
#: of the stretched volume (module docstring), the one definition (:func:`k_moments`, :func:`k_moments_dd`)
MQ = np.array([[1.0, -1.5, 1.0, -0.25],
               [0.0, 0.5, -2.0 / 3.0, 0.25],
               [0.0, 0.0, 1.0 / 3.0, -0.25],
               [0.0, 0.0, 0.0, 0.25]])


@njit(cache=True, inline="always")
def k_moments(t, out):
    """out[q] = M_q(t), q = 0..3 (any scalar type); their t-derivatives are the integrand (1 - t)^(3-q) t^q."""
    t2 = t * t
    t3 = t2 * t
    t4 = t3 * t
    for q in range(4):
        out[q] = MQ[q, 0] * t + MQ[q, 1] * t2 + MQ[q, 2] * t3 + MQ[q, 3] * t4


@njit(cache=True, inline="always")
def k_moments_dd(a, b, out):
    """out[q] = (M_q(b) - M_q(a)) / (b - a), exact for a = b too and free of cancellation: the polynomials' divided
    differences, (b^p - a^p)/(b - a) by dd_p = a dd_(p-1) + b^(p-1)."""
    d2 = a + b
    d3 = a * d2 + b * b
    d4 = a * d3 + b * b * b
    for q in range(4):
        out[q] = MQ[q, 0] + MQ[q, 1] * d2 + MQ[q, 2] * d3 + MQ[q, 3] * d4


@njit(cache=True, inline="always")
def k_piece_volume(Ra, Rb, ga, gb, S, ds):
    """The stretched volume of the piece of an element between two local coordinates, ds pi sum_(ijl) R_i R_j gamma_l
    S_(i+j+l) over its end nodes i, j, l in {0, 1} (radii Ra, Rb and stretches ga, gb), S[q] = M_q(t_hi) - M_q(t_lo)
    (:func:`k_moments`).  Any scalar type."""
    acc = 0.0 * S[0]
    for i in range(2):
        for j in range(2):
            for l in range(2):
                acc += (Ra if i == 0 else Rb) * (Ra if j == 0 else Rb) * (ga if l == 0 else gb) * S[i + j + l]
    return ds * math.pi * acc


@njit(cache=True)
def _element_piece(R, gamma, e, e0, t0, e1, t1, periodic, Rl, gl):
    """Load element e's nodal radii and stretches into Rl, gl; return the local interval [lo, hi] of
    the parcel (e0, t0)-(e1, t1) on it."""
    nR = R.shape[0]
    for i in range(2):
        node = (e + i) % nR if periodic else e + i
        Rl[i] = R[node]
        gl[i] = gamma[node]
    return (t0 if e == e0 else 0.0), (t1 if e == e1 else 1.0)


@njit(cache=True, inline="always")
def k_whole_element(a, b, ga, gb):
    """The whole element's stretched volume (:func:`k_piece_volume` over [0, 1]) times 12 / (ds pi),
    ga (3a^2 + 2ab + b^2) + gb (a^2 + 2ab + 3b^2), with its first derivatives in (a, b, ga, gb) and its second ones
    (a a, b b, a b, a ga, a gb, b ga, b gb; the rest vanish), for end radii a, b and stretches ga, gb: the tube's volume
    under the external pressure (varint.terms.coupled).  Scalars or arrays (elementwise)."""
    fa = 3 * a * a + 2 * a * b + b * b
    fb = a * a + 2 * a * b + 3 * b * b
    return (ga * fa + gb * fb, ga * (6 * a + 2 * b) + gb * (2 * a + 2 * b), ga * (2 * a + 2 * b) + gb * (2 * a + 6 * b),
            fa, fb, 6 * ga + 2 * gb, 2 * ga + 6 * gb, 2 * ga + 2 * gb, 6 * a + 2 * b, 2 * a + 2 * b, 2 * a + 2 * b,
            2 * a + 6 * b)


@njit(cache=True)
def _k_parcel_volume(s, R, gamma, ds, periodic, k, Rl, gl, Mh, Ml):
    """V_k of the parcel [s_k, s_{k+1}]: its pieces on the elements it covers (:func:`k_piece_volume`)."""
    nR = R.shape[0]
    e0, t0, _ = k_locate(s[k], ds, nR, periodic)
    e1, t1, _ = k_locate(s[k + 1], ds, nR, periodic)
    v = 0.0
    for e in range(e0, e1 + 1):
        lo, hi = _element_piece(R, gamma, e, e0, t0, e1, t1, periodic, Rl, gl)
        k_moments(hi, Mh)
        k_moments(lo, Ml)
        for q in range(4):
            Mh[q] -= Ml[q]
        v += k_piece_volume(Rl[0], Rl[1], gl[0], gl[1], Mh, ds)
    return v


@njit(cache=True)
def _k_stretched_volumes(s, R, gamma, ds, periodic, V):
    Rl, gl, Mh, Ml = np.empty(2), np.empty(2), np.empty(4), np.empty(4)
    for k in range(s.shape[0] - 1):
        V[k] = _k_parcel_volume(s, R, gamma, ds, periodic, k, Rl, gl, Mh, Ml)


@njit(cache=True)
def _add_element(Rl, gl, t, sign, ds, slot, n_nodes, g, H):
    """Add sign * (gradient, Hessian) of G_e(t) in (R, gamma) of the element's two nodes.

    Local layout: g[2 + m] radius of local node m, g[2 + n_nodes + m] its stretch; ``slot`` is the
    element's first local node.
    """
    Mq = np.empty(4)
    k_moments(t, Mq)
    c = sign * ds * math.pi
    for i in range(2):
        iR = 2 + slot + i
        ig = 2 + n_nodes + slot + i
        dR = 0.0
        dg = 0.0
        for j in range(2):
            for l in range(2):
                dR += 2.0 * Rl[j] * gl[l] * Mq[i + j + l]
                dg += Rl[j] * Rl[l] * Mq[j + l + i]
        g[iR] += c * dR
        g[ig] += c * dg
        for j in range(2):
            jR = 2 + slot + j
            jg = 2 + n_nodes + slot + j
            hRR = 0.0
            hRg = 0.0
            for l in range(2):
                hRR += 2.0 * gl[l] * Mq[i + j + l]
                hRg += 2.0 * Rl[l] * Mq[i + l + j]
            H[iR, jR] += c * hRR
            H[iR, jg] += c * hRg
            H[jg, iR] += c * hRg


@njit(cache=True)
def _add_end(Rl, gl, t, sign, ds, slot, n_nodes, label, g, H):
    """The end-label rows: d/ds of G_e(t(s)) is pi R(t)^2 gamma(t) (sign -1 at s_k, +1 at s_{k+1})."""
    Rt = Rl[0] * (1.0 - t) + Rl[1] * t
    gt = gl[0] * (1.0 - t) + gl[1] * t
    phi0 = 1.0 - t
    phi1 = t
    c = sign * math.pi
    g[label] += c * Rt * Rt * gt
    H[label, label] += c * (2.0 * Rt * (Rl[1] - Rl[0]) * gt + Rt * Rt * (gl[1] - gl[0])) / ds
    for i, phi in ((0, phi0), (1, phi1)):
        iR = 2 + slot + i
        ig = 2 + n_nodes + slot + i
        H[label, iR] += c * 2.0 * Rt * gt * phi
        H[iR, label] += c * 2.0 * Rt * gt * phi
        H[label, ig] += c * Rt * Rt * phi
        H[ig, label] += c * Rt * Rt * phi


@njit(cache=True)
def k_stretched_derivatives(s, R, gamma, ds, periodic, n_nodes, V, index, grad, hess):
    nR = R.shape[0]
    M = s.shape[0] - 1
    Rl, gl, Mh, Ml = np.empty(2), np.empty(2), np.empty(4), np.empty(4)
    for k in range(M):
        V[k] = _k_parcel_volume(s, R, gamma, ds, periodic, k, Rl, gl, Mh, Ml)
        e0, t0, _ = k_locate(s[k], ds, nR, periodic)
        e1, t1, _ = k_locate(s[k + 1], ds, nR, periodic)
        g = grad[k]
        H = hess[k]
        index[k, 0] = k
        index[k, 1] = k + 1
        for m in range(e1 - e0 + 2):
            node = (e0 + m) % nR if periodic else e0 + m
            index[k, 2 + m] = M + 1 + node
            index[k, 2 + n_nodes + m] = M + 1 + nR + node
        for e in range(e0, e1 + 1):
            slot = e - e0
            lo, hi = _element_piece(R, gamma, e, e0, t0, e1, t1, periodic, Rl, gl)
            _add_element(Rl, gl, hi, 1.0, ds, slot, n_nodes, g, H)
            _add_element(Rl, gl, lo, -1.0, ds, slot, n_nodes, g, H)
            if e == e1:
                _add_end(Rl, gl, t1, 1.0, ds, slot, n_nodes, 1, g, H)
            if e == e0:
                _add_end(Rl, gl, t0, -1.0, ds, slot, n_nodes, 0, g, H)
