"""Potential terms of the discrete Lagrangian, one class per physical effect.

Each term is evaluated on a :class:`Config` (label positions ``s``, nodal
radii ``R``, multipliers ``mu``) and returns its value, its gradient in
configuration index space and its Hessian as COO triples.  Each declares

* ``touches``: the configuration blocks it depends on (its Jacobian sparsity);
* ``breaks``: the invariants of the straight tube it destroys.

The model's expected invariants are computed from these declarations
(:meth:`varint.model.model.Model.invariants`), never listed by hand.
Equation references are to the paper (``Lagrangian_fluid_tube``,
``lagr_compressible_simple``, ``lagr_incompressible_simple``, ``Pedley_Luo_F``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..lattice.parcels import parcel_derivatives, parcel_volumes, tube_volume

__all__ = ["Config", "InternalEnergy", "Incompressibility", "WallLinear", "WallTubeLaw",
           "ExternalPressure", "Gravity"]


@dataclass
class Config:
    """One configuration of the lattice: labels s (M+1,), radii R (nR,), multipliers mu (M,) or None."""

    s: np.ndarray
    R: np.ndarray
    mu: np.ndarray | None = None


class Term:
    name = "term"
    touches = ()
    breaks = frozenset()

    def energy(self, cfg, cache):
        raise NotImplementedError

    def gradient(self, cfg, cache, gs, gR, gmu):
        raise NotImplementedError

    def hessian(self, cfg, cache, index):
        """COO triples (rows, cols, vals) in configuration index space."""
        raise NotImplementedError


def _coo_empty():
    return np.empty(0, np.int64), np.empty(0, np.int64), np.empty(0)


class _ParcelTerm(Term):
    """Shared access to the parcel volumes (cached per configuration).

    The labels are checked once per evaluation by :class:`varint.model.model.Model` (which returns NaN for a
    folded lattice before any term runs), so the terms call the kernels unchecked; the kernels stay in
    bounds whatever the labels.
    """

    def __init__(self, geom):
        self.geom = geom  # (ds, periodic, R_is_unknown)

    def volumes(self, cfg, cache):
        if "V" not in cache:
            ds, periodic, _ = self.geom
            cache["V"] = parcel_volumes(cfg.s, cfg.R, ds, periodic, check=False)
        return cache["V"]


class InternalEnergy(_ParcelTerm):
    """sum_k m_k e(m_k / V_k, S_k): the fluid's internal energy (``xi e(rho, S)``)."""

    name = "internal"
    touches = ("s", "R")
    breaks = frozenset()

    def __init__(self, geom, eos, m, S, uniform_rigid):
        super().__init__(geom)
        self.eos, self.m, self.S = eos, m, S
        # a moving wall or a non-uniform duct exchanges axial momentum with the fluid
        self.breaks = frozenset() if uniform_rigid else frozenset({"axial_momentum"})

    def energy(self, cfg, cache):
        return float(np.sum(self.eos.psi(self.volumes(cfg, cache), self.m, self.S)))

    def _coeffs(self, cfg, cache):
        d1, d2 = self.eos.dpsi(self.volumes(cfg, cache), self.m, self.S)
        return d1, d2

    def gradient(self, cfg, cache, gs, gR, gmu):
        ds, periodic, want_R = self.geom
        d1, d2 = self._coeffs(cfg, cache)
        a, b, _, _ = parcel_derivatives(cfg.s, cfg.R, ds, periodic, d1, d2, want_R, False, check=False)
        gs += a
        if want_R:
            gR += b

    def hessian(self, cfg, cache, index):
        ds, periodic, want_R = self.geom
        d1, d2 = self._coeffs(cfg, cache)
        _, _, H, _ = parcel_derivatives(cfg.s, cfg.R, ds, periodic, d1, d2, want_R, True, check=False)
        return H


class Incompressibility(_ParcelTerm):
    """-sum_k mu_k (V_k - V0_k): the constraint of ``variations_incompressible_simple``.

    Written with the sign of a potential so that the step is stationarity of
    K - U; mu is then the pressure (``incompressible_system``).
    """

    name = "incompressibility"
    touches = ("s", "R", "mu")
    breaks = frozenset()

    def __init__(self, geom, V0, uniform_rigid):
        super().__init__(geom)
        self.V0 = V0
        self.breaks = frozenset() if uniform_rigid else frozenset({"axial_momentum"})

    def energy(self, cfg, cache):
        return -float(np.dot(cfg.mu, self.volumes(cfg, cache) - self.V0))

    def gradient(self, cfg, cache, gs, gR, gmu):
        ds, periodic, want_R = self.geom
        zero = np.zeros_like(cfg.mu)
        a, b, _, _ = parcel_derivatives(cfg.s, cfg.R, ds, periodic, -cfg.mu, zero, want_R, False, check=False)
        gs += a
        if want_R:
            gR += b
        gmu -= self.volumes(cfg, cache) - self.V0

    def hessian(self, cfg, cache, index):
        ds, periodic, want_R = self.geom
        zero = np.zeros_like(cfg.mu)
        _, _, (r, c, v), (jr, jc, jv) = parcel_derivatives(cfg.s, cfg.R, ds, periodic, -cfg.mu, zero, want_R, True, check=False)
        jr = jr + index["mu"]
        return (np.concatenate([r, jr, jc]), np.concatenate([c, jc, jr]), np.concatenate([v, -jv, -jv]))


class _NodalWall(Term):
    touches = ("R",)
    breaks = frozenset({"axial_momentum"})

    def __init__(self, ds, weights, periodic):
        self.ds, self.w, self.periodic = ds, weights, periodic
        n = len(weights)
        self.ia = np.arange(n if periodic else n - 1)
        self.ib = (self.ia + 1) % n


class WallLinear(_NodalWall):
    """F(R, R') = 1/2 beta1 R'^2 + 1/2 beta2 (R - R0)^2 (paper §4.3, eq. ``beta_1_2``).

    R' is the difference quotient on each element, the (R - R0)^2 part is lumped
    at the nodes with the trapezoidal weights ``w``.
    """

    name = "wall_elastic"

    def __init__(self, ds, weights, periodic, beta1, beta2, R0):
        super().__init__(ds, weights, periodic)
        self.beta1, self.beta2, self.R0 = beta1, beta2, R0

    def energy(self, cfg, cache):
        d = (cfg.R[self.ib] - cfg.R[self.ia]) / self.ds
        return float(0.5 * self.beta1 * self.ds * np.sum(d * d) + 0.5 * self.beta2 * np.sum(self.w * (cfg.R - self.R0) ** 2))

    def gradient(self, cfg, cache, gs, gR, gmu):
        d = (cfg.R[self.ib] - cfg.R[self.ia]) / self.ds
        f = self.beta1 * d
        np.add.at(gR, self.ib, f)
        np.add.at(gR, self.ia, -f)
        gR += self.beta2 * self.w * (cfg.R - self.R0)

    def hessian(self, cfg, cache, index):
        o = index["R"]
        k = self.beta1 / self.ds
        n = len(self.w)
        ia, ib = self.ia + o, self.ib + o
        diag = np.arange(n) + o
        rows = np.concatenate([ia, ib, ia, ib, diag])
        cols = np.concatenate([ia, ib, ib, ia, diag])
        m = len(ia)
        vals = np.concatenate([np.full(m, k), np.full(m, k), np.full(m, -k), np.full(m, -k), self.beta2 * self.w])
        return rows, cols, vals


class WallTubeLaw(_NodalWall):
    """Pedley-Luo tube law (eq. ``Pedley_Luo_F``): F = T/2 (dA/ds)^2 + f(A), f'(A) = Phi(A).

    Phi(A) = beta (sqrt(A) - sqrt(A0)) / sqrt(A0), so f(A) = beta (2/3 A^{3/2}/sqrt(A0) - A + A0/3)
    with f(A0) = 0.  External pressure enters through the separate
    :class:`ExternalPressure` term (the paper's A p_ext inside F is that term).
    """

    name = "wall_elastic"

    def __init__(self, ds, weights, periodic, stiffness, tension, R0):
        super().__init__(ds, weights, periodic)
        self.beta, self.T = stiffness, tension
        self.A0 = math.pi * R0 * R0

    def _f(self, A):
        return self.beta * (2.0 / 3.0 * A ** 1.5 / math.sqrt(self.A0) - A + self.A0 / 3.0)

    def _phi(self, A):
        return self.beta * (np.sqrt(A) - math.sqrt(self.A0)) / math.sqrt(self.A0)

    def energy(self, cfg, cache):
        A = math.pi * cfg.R ** 2
        d = (A[self.ib] - A[self.ia]) / self.ds
        return float(0.5 * self.T * self.ds * np.sum(d * d) + np.sum(self.w * self._f(A)))

    def gradient(self, cfg, cache, gs, gR, gmu):
        R = cfg.R
        A = math.pi * R ** 2
        d = (A[self.ib] - A[self.ia]) / self.ds
        f = self.T * d * 2 * math.pi
        np.add.at(gR, self.ib, f * R[self.ib])
        np.add.at(gR, self.ia, -f * R[self.ia])
        gR += self.w * self._phi(A) * 2 * math.pi * R

    def hessian(self, cfg, cache, index):
        R = cfg.R
        A = math.pi * R ** 2
        o = index["R"]
        d = (A[self.ib] - A[self.ia]) / self.ds
        ga = -2 * math.pi * R[self.ia] / self.ds
        gb = 2 * math.pi * R[self.ib] / self.ds
        c = self.T * self.ds
        ia, ib = self.ia + o, self.ib + o
        n = len(R)
        dphi = self.beta / (2.0 * np.sqrt(A) * math.sqrt(self.A0))
        nodal = self.w * (dphi * (2 * math.pi * R) ** 2 + self._phi(A) * 2 * math.pi)
        diag = np.arange(n) + o
        rows = np.concatenate([ia, ib, ia, ib, diag])
        cols = np.concatenate([ia, ib, ib, ia, diag])
        vals = np.concatenate([c * (ga * ga + d * (-2 * math.pi / self.ds)), c * (gb * gb + d * (2 * math.pi / self.ds)),
                               c * ga * gb, c * ga * gb, nodal])
        return rows, cols, vals


class ExternalPressure(Term):
    """p_ext Q integrated: the work of the outside pressure on the tube volume (``Lagrangian_fluid_tube``)."""

    name = "external_pressure"
    touches = ("R",)
    breaks = frozenset({"axial_momentum"})

    def __init__(self, ds, periodic, p_ext):
        self.ds, self.periodic, self.p_ext = ds, periodic, p_ext

    def energy(self, cfg, cache):
        return self.p_ext * tube_volume(cfg.R, self.ds, self.periodic)[0]

    def gradient(self, cfg, cache, gs, gR, gmu):
        gR += self.p_ext * tube_volume(cfg.R, self.ds, self.periodic)[1]

    def hessian(self, cfg, cache, index):
        r, c, v = tube_volume(cfg.R, self.ds, self.periodic)[2]
        return r + index["R"], c + index["R"], self.p_ext * v


class Gravity(Term):
    """-sum_k m_k g_x s_k: gravity along the (fixed, straight) tube axis acting on the labels' lumped masses."""

    name = "gravity"
    touches = ("s",)
    breaks = frozenset({"axial_momentum"})

    def __init__(self, label_mass, gx):
        self.mlab, self.gx = label_mass, gx

    def energy(self, cfg, cache):
        return -self.gx * float(np.dot(self.mlab, cfg.s))

    def gradient(self, cfg, cache, gs, gR, gmu):
        gs -= self.gx * self.mlab

    def hessian(self, cfg, cache, index):
        return _coo_empty()
