"""SO(3) utilities for the Cayley-map integrators (docs/theory.md §9).

Readable NumPy references first, batched numba kernels at the bottom; tests check
the group identities, the derivatives against finite differences and that the
kernels equal the references.  No epsilon anywhere: the Cayley map is rational.

    cay(w)     = I + 4/(4+|w|^2) (w^ + w^ w^ / 2) = (I - w^/2)^-1 (I + w^/2)
    cay^-1(L)  = 2/(1 + tr L) vee(L - L^T)            (defined for rotations by less than pi)
    dcay_w     = 4/(4+|w|^2) (I + w^/2)               right-trivialised: d cay cay^-1 = (dcay_w dw)^
    dcay_w^-1  = I - w^/2 + w w^T / 4
    cay(w)^-1 d cay = (dcay_{-w} dw)^                 (left-trivialised)
    half(w)    = w / (1 + sqrt(1 + |w|^2/4)):  cay(half(w))^2 = cay(w)  (the symmetric midpoint)
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["hat", "vee", "cay", "cay_inv", "dcay", "dcay_inv", "half", "cay_batch", "cay_inv_batch",
           "orthogonality_error", "k_hat", "k_cay", "k_cay_inv", "k_body"]


def _arr(x):
    """float64 array, or complex128 if complex (the rod's complex-step derivatives pass through here)."""
    x = np.asarray(x)
    return x if np.iscomplexobj(x) else x.astype(np.float64, copy=False)


def hat(w):
    """Skew matrix of w (..., 3) -> (..., 3, 3): hat(w) @ v = w x v."""
    w = _arr(w)
    out = np.zeros(w.shape + (3,), dtype=w.dtype)
    out[..., 0, 1], out[..., 0, 2] = -w[..., 2], w[..., 1]
    out[..., 1, 0], out[..., 1, 2] = w[..., 2], -w[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -w[..., 1], w[..., 0]
    return out


def vee(A):
    """Inverse of hat on the skew part: (..., 3, 3) -> (..., 3)."""
    A = np.asarray(A)
    return 0.5 * np.stack([A[..., 2, 1] - A[..., 1, 2], A[..., 0, 2] - A[..., 2, 0], A[..., 1, 0] - A[..., 0, 1]], axis=-1)


def cay(w):
    w = _arr(w)
    W = hat(w)
    c = 4.0 / (4.0 + np.sum(w * w, axis=-1))
    return np.eye(3) + c[..., None, None] * (W + 0.5 * W @ W)


def cay_inv(L):
    L = _arr(L)
    tr = np.trace(L, axis1=-2, axis2=-1)
    return (2.0 / (1.0 + tr))[..., None] * 2.0 * vee(L)  # vee of (L - L^T) is 2 vee(L) on the skew part


def dcay(w):
    w = _arr(w)
    c = 4.0 / (4.0 + np.sum(w * w, axis=-1))
    return c[..., None, None] * (np.eye(3) + 0.5 * hat(w))


def dcay_inv(w):
    w = _arr(w)
    return np.eye(3) - 0.5 * hat(w) + 0.25 * w[..., :, None] * w[..., None, :]


def half(w):
    """Cayley parameter of the half rotation: cay(half(w)) @ cay(half(w)) == cay(w)."""
    w = _arr(w)
    return w / (1.0 + np.sqrt(1.0 + 0.25 * np.sum(w * w, axis=-1)))[..., None]


def orthogonality_error(L):
    """max ||L^T L - I|| (Frobenius) over a batch of frames."""
    L = np.asarray(L)
    E = np.swapaxes(L, -1, -2) @ L - np.eye(3)
    return float(np.max(np.sqrt(np.sum(E * E, axis=(-2, -1)))))


# ---------------------------------------------------------------------------
# numba kernels (batched, write into preallocated outputs)


@njit(cache=True, inline="always")
def k_body(L, v, i):
    """Component i of L^T v: a spatial vector v in the body frame of L (any scalar type)."""
    return L[0, i] * v[0] + L[1, i] * v[1] + L[2, i] * v[2]


@njit(cache=True, inline="always")
def k_hat(w, c, out):
    """out = c hat(w) for one vector w (3,) into out (3, 3): :func:`hat` of the compiled kernels (any scalar type:
    real, or complex for complex steps)."""
    out[0, 0] = out[1, 1] = out[2, 2] = 0.0
    out[0, 1], out[0, 2], out[1, 2] = -c * w[2], c * w[1], -c * w[0]
    out[1, 0], out[2, 0], out[2, 1] = c * w[2], -c * w[1], c * w[0]


@njit(cache=True, inline="always")
def k_cay(w0, w1, w2, out):
    """out = cay(w) for one w = (w0, w1, w2) into out (3, 3) (any scalar type): :func:`cay` of the compiled kernels,
    I + c (W + W W / 2) with W = hat(w), c = 4 / (4 + |w|^2)."""
    c = 4.0 / (4.0 + w0 * w0 + w1 * w1 + w2 * w2)
    out[0, 0] = 1.0 - 0.5 * c * (w1 * w1 + w2 * w2)
    out[1, 1] = 1.0 - 0.5 * c * (w0 * w0 + w2 * w2)
    out[2, 2] = 1.0 - 0.5 * c * (w0 * w0 + w1 * w1)
    out[0, 1] = c * (-w2 + 0.5 * w0 * w1)
    out[1, 0] = c * (w2 + 0.5 * w0 * w1)
    out[0, 2] = c * (w1 + 0.5 * w0 * w2)
    out[2, 0] = c * (-w1 + 0.5 * w0 * w2)
    out[1, 2] = c * (-w0 + 0.5 * w1 * w2)
    out[2, 1] = c * (w0 + 0.5 * w1 * w2)


@njit(cache=True, inline="always")
def k_cay_inv(L, out):
    """out = cay^-1(L) = 2 a / c for one L (3, 3) (any scalar type): :func:`cay_inv` of the compiled kernels.  Returns
    (c, a0, a1, a2): c = 1 + tr L and a the axial vector of L - L^T (unhalved), the two pieces the energy-momentum
    discrete gradient differentiates (varint.schemes.em_rod)."""
    a0 = L[2, 1] - L[1, 2]
    a1 = L[0, 2] - L[2, 0]
    a2 = L[1, 0] - L[0, 1]
    c = 1.0 + L[0, 0] + L[1, 1] + L[2, 2]
    f = 2.0 / c
    out[0], out[1], out[2] = f * a0, f * a1, f * a2
    return c, a0, a1, a2


@njit(cache=True)
def cay_batch(w, out):
    """out[i] = cay(w[i]) for w (n, 3), out (n, 3, 3)."""
    for i in range(w.shape[0]):
        k_cay(w[i, 0], w[i, 1], w[i, 2], out[i])
    return out


@njit(cache=True)
def cay_inv_batch(L, out):
    """out[i] = cay^-1(L[i]) for L (n, 3, 3), out (n, 3)."""
    for i in range(L.shape[0]):
        k_cay_inv(L[i], out[i])
    return out
