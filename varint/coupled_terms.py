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
"""

from __future__ import annotations

import numpy as np

from .coupled_geometry import centreline_and_weights

__all__ = ["fluid_kinetic_step", "LOCAL_SIZE"]

#: local unknowns of one label's kinetic contribution: s^n, r^n (4 nodes x 3), s^{n+1}, r^{n+1} (4 x 3)
LOCAL_SIZE = 26


def fluid_kinetic_step(s0, r0, s1, r1, mbar, h, ds, periodic=False, period=None):
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
        where a closed end folds a ghost node onto a real one: sum the entries).
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

    # Hessian: c (JD^T JD + sum_c D_c d2 D_c); X is linear in r, so d2 D_c lives on (s, s) and (s, r) only
    hess = c[:, None, None] * np.einsum("kcu,kcv->kuv", JD, JD)
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
