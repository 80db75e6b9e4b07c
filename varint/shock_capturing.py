"""Shock capturing on the straight rigid uniform tube: an artificial viscous pressure by the discrete
Lagrange–d'Alembert principle, the heating it causes, and an energy-exact pressure (docs/theory.md,
"Shock capturing").

The conservative scheme (docs/theory.md §4) cannot carry a shock: the midpoint rule has no way to turn
kinetic energy into heat, so a steepening wave rings.  Scene section ``[shock_capturing]`` adds one
non-conservative force (:class:`ShockCapturing`, a :class:`varint.forces.Force`) that does three things:

1. **Viscous pressure** (von Neumann & Richtmyer, J. Appl. Phys. 21, 232 (1950); the linear term of
   Landshoff, LANL report LA-1430 (1955)), in compression only:

       Q_k = rho_k (c_Q^2 du_k^2 + c_L c_k |du_k|)   if du_k < 0,  else 0,
       du_k = (s_{k+1}^{n+1} - s_{k+1}^n - s_k^{n+1} + s_k^n) / h,

   the jump of the step's mean label velocity across parcel k, with rho_k = m_k / Vbar_k and the sound
   speed c_k at the step's midpoint volume Vbar_k = (V_k^n + V_k^{n+1}) / 2.  Q acts like an extra
   pressure at the midpoint: f^- = f^+ = (h/2) sum_k Q_k dV_k/ds (Marsden & West 2001, §3.2).
2. **Mean-value pressure.**  The midpoint pressure p(Vbar_k) is replaced by the discrete gradient
   Ptilde_k = -(E_k(V_k^{n+1}) - E_k(V_k^n)) / (V_k^{n+1} - V_k^n) (Gonzalez, J. Nonlinear Sci. 6, 449
   (1996)), entered as a second force (Ptilde_k - p(Vbar_k)) of the same form.  With V linear in the
   labels (rigid uniform tube) the kinetic energy then changes by exactly sum_k (Ptilde_k + Q_k) dV_k.
3. **Heating** (:meth:`ShockCapturing.after_step`): once a step is accepted each parcel's entropy rises so
   that its internal energy at the new volume grows by the viscous work W_k = -Q_k (V_k^{n+1} - V_k^n) >= 0.

Together: kinetic + internal energy is conserved to the Newton tolerance, the axial momentum of a periodic
tube too (the forces are differences of parcel quantities), and no parcel's entropy decreases.

Only an ideal gas in a rigid uniform tube (no ``[wall]``, no ``tube.area_table``, no ``[rod]``) with the
midpoint scheme: there V_k = A (s_{k+1} - s_k) and the heating has a closed form (varint.scene refuses
the rest in one line).  Kernels are numba; tests/test_shock_capturing.py checks each one against finite
differences or the closed forms.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp
from numba import njit

from .forces import Declaration, Force

__all__ = ["ShockCapturing", "mean_value_pressure", "viscous_pressure", "heated_entropy"]

#: below this |V1/V0 - 1| the mean-value pressure's derivative is taken from its Taylor series
_SERIES = 1e-3


@njit(cache=True)
def _mean_value_pressure(V0, V1, K, gamma, P, dP):
    """Ptilde = -(E(V1) - E(V0)) / (V1 - V0) of E(V) = K V^(1-gamma) / (gamma - 1), and dPtilde/dV1.

    Written as p0 phi(x), p0 = K V0^-gamma, x = V1/V0 - 1, phi(x) = -expm1((1-gamma) log1p(x)) / ((gamma-1) x):
    expm1 and log1p keep phi accurate to round-off down to x -> 0 (phi(0) = 1, the pressure at V0 = V1).
    dphi/dx has a cancellation near 0 and is then taken from phi's series,
    phi = 1 - g/2 x + g(g+1)/6 x^2 - g(g+1)(g+2)/24 x^3 + g(g+1)(g+2)(g+3)/120 x^4 - ...
    """
    for k in range(V0.shape[0]):
        p0 = K[k] * V0[k] ** (-gamma)
        x = V1[k] / V0[k] - 1.0
        g = gamma
        if x == 0.0:
            phi = 1.0
        else:
            phi = -math.expm1((1.0 - g) * math.log1p(x)) / ((g - 1.0) * x)
        if abs(x) < _SERIES:
            c1 = -g / 2.0
            c2 = g * (g + 1.0) / 6.0
            c3 = -g * (g + 1.0) * (g + 2.0) / 24.0
            c4 = g * (g + 1.0) * (g + 2.0) * (g + 3.0) / 120.0
            dphi = c1 + x * (2.0 * c2 + x * (3.0 * c3 + x * 4.0 * c4))
        else:
            # phi' = [(g-1) (1+x)^-g x - (1 - (1+x)^(1-g))] / ((g-1) x^2)
            dphi = ((g - 1.0) * (1.0 + x) ** (-g) * x + math.expm1((1.0 - g) * math.log1p(x))) / ((g - 1.0) * x * x)
        P[k] = p0 * phi
        dP[k] = p0 * dphi / V0[k]


@njit(cache=True)
def _viscous_pressure(V0, V1, m, K, gamma, A, h, cQ, cL, Q, dQ):
    """Q_k = rho (c_Q^2 d^2 + c_L c d), d = max(0, -du), du = (V1 - V0)/(A h), rho and c at Vbar; dQ/dV1."""
    for k in range(V0.shape[0]):
        du = (V1[k] - V0[k]) / (A * h)
        if du >= 0.0:
            Q[k] = 0.0
            dQ[k] = 0.0
            continue
        d = -du
        dd = -1.0 / (A * h)  # d(d)/dV1: compressing further (V1 smaller) raises d
        Vb = 0.5 * (V0[k] + V1[k])
        rho = m[k] / Vb
        c = math.sqrt(gamma * K[k] * Vb ** (-gamma) / rho)
        drho = -0.5 * rho / Vb  # d rho / dV1 (dVbar/dV1 = 1/2)
        dc = 0.25 * (1.0 - gamma) * c / Vb  # c ~ Vbar^((1-gamma)/2)
        f = cQ * cQ * d * d + cL * c * d
        df = 2.0 * cQ * cQ * d * dd + cL * (dc * d + c * dd)
        Q[k] = rho * f
        dQ[k] = drho * f + rho * df


@njit(cache=True)
def _heated_entropy(S, V1, K, W, gamma, cv, out):
    """S' with E(V1, S') = E(V1, S) + W for E = K(S) V^(1-gamma)/(gamma-1), K ~ exp(S/cv): S' = S + cv log1p(W/E)."""
    for k in range(S.shape[0]):
        E = K[k] * V1[k] ** (1.0 - gamma) / (gamma - 1.0)
        out[k] = S[k] + cv * math.log1p(W[k] / E)


def mean_value_pressure(V0, V1, K, gamma):
    """(Ptilde, dPtilde/dV1) per parcel for an ideal gas p = K V^-gamma (K = exp(S/c_v) m^gamma)."""
    V0, V1, K = (np.ascontiguousarray(a, dtype=np.float64) for a in (V0, V1, K))
    P, dP = np.empty_like(V0), np.empty_like(V0)
    _mean_value_pressure(V0, V1, K, float(gamma), P, dP)
    return P, dP


def viscous_pressure(V0, V1, m, K, gamma, A, h, cQ, cL):
    """(Q, dQ/dV1) per parcel (module docstring, item 1)."""
    V0, V1, m, K = (np.ascontiguousarray(a, dtype=np.float64) for a in (V0, V1, m, K))
    Q, dQ = np.empty_like(V0), np.empty_like(V0)
    _viscous_pressure(V0, V1, m, K, float(gamma), float(A), float(h), float(cQ), float(cL), Q, dQ)
    return Q, dQ


def heated_entropy(S, V1, K, W, gamma, cv):
    """Entropies after heating each parcel by W >= 0 at volume V1 (module docstring, item 3)."""
    S, V1, K, W = (np.ascontiguousarray(a, dtype=np.float64) for a in (S, V1, K, W))
    out = np.empty_like(S)
    _heated_entropy(S, V1, K, W, float(gamma), float(cv), out)
    return out


class ShockCapturing(Force):
    """The ``[shock_capturing]`` force on a :class:`varint.tube.TubePart` (module docstring).

    f^- = f^+ = (h/2) G^T X with X_k = Ptilde_k - p(Vbar_k) + Q_k and G = dV/dz = A D B_s (constant: the
    tube is rigid and uniform; D the parcels' label difference, B_s the labels' selection); its Jacobian (h/2) G^T diag(dX/dV^{n+1}) G is exact.  ``after_step`` heats the
    parcels by the viscous work (``tube.S`` in place: the internal-energy term and the monitors read the
    same array).  ``last_work`` is the viscous work of the last accepted step (sum of W_k, J).
    """

    declaration = Declaration("shock_capturing", {"parcel_entropy": None})

    def __init__(self, tube, keys):
        eos = tube.eos
        self.tube = tube
        self.gamma, self.cv = eos.gamma, eos.cv
        self.cQ, self.cL = float(keys.quadratic), float(keys.linear)
        self.A = math.pi * float(tube.R0) ** 2
        M = tube.M
        # The labels are s = c0_s + B_s z with B_s a 0/1 selection (interior labels; a periodic tube's s_M
        # is s_0 + L): keep its (label, z) pairs and apply it by indexing rather than sparse products.
        Bs = tube.B[: M + 1, :].tocoo()
        self.lab, self.col = Bs.row.astype(np.int64), Bs.col.astype(np.int64)
        self.c0 = tube.c0[: M + 1].copy()
        self.nz = tube.nz
        # Jacobian pattern of (h/2) G^T diag(dX) G, G = A D B_s: parcel k couples labels k and k+1
        zof = np.full(M + 1, -1, np.int64)
        zof[self.lab] = self.col
        if tube.periodic:
            zof[M] = zof[0]
        k = np.arange(M)
        a, b = zof[k], zof[k + 1]
        rows = np.concatenate([a, b, a, b])
        cols = np.concatenate([a, b, b, a])
        sign = np.concatenate([np.ones(M), np.ones(M), -np.ones(M), -np.ones(M)])
        keep = (rows >= 0) & (cols >= 0)
        self._jrows, self._jcols, self._jsign = rows[keep], cols[keep], sign[keep]
        self._jpar = np.tile(k, 4)[keep]
        self.last_work = 0.0

    # -- the two levels --------------------------------------------------------------------

    def _volumes(self, q, lam):
        s = self.c0.copy()
        s[self.lab] += q[self.col]  # labels are inertial unknowns: q holds them (lam does not)
        return self.A * np.diff(s)

    def _GT(self, X):
        """G^T X = B_s^T (A D^T X): label j gets A (X_{j-1} - X_j)."""
        g = np.zeros(len(X) + 1)
        g[:-1] -= X
        g[1:] += X
        return self.A * np.bincount(self.col, weights=g[self.lab], minlength=self.nz)

    def _K(self):
        t = self.tube
        return np.exp(t.S / self.cv) * t.m ** self.gamma

    def pressures(self, pt):
        """Per parcel at the step ``pt``: (X, dX/dV1, Q, V0, V1) with X = Ptilde - p(Vbar) + Q."""
        V0, V1 = self._volumes(pt.q0, pt.lam), self._volumes(pt.q1, pt.lam)
        K = self._K()
        g = self.gamma
        P, dP = mean_value_pressure(V0, V1, K, g)
        Q, dQ = viscous_pressure(V0, V1, self.tube.m, K, g, self.A, pt.h, self.cQ, self.cL)
        Vb = 0.5 * (V0 + V1)
        pb = K * Vb ** (-g)
        dpb = -0.5 * g * pb / Vb
        return P - pb + Q, dP - dpb + dQ, Q, V0, V1

    # -- Force interface ---------------------------------------------------------------------

    def add(self, pt, d, level):
        """f^- (level 0) = f^+ (level 1) = (h/2) G^T X into the tube's inertial block."""
        X = self.pressures(pt)[0]
        d.tube_q += 0.5 * pt.h * self._GT(X)

    def jacobian(self, pt):
        """d f^- / dz = (h/2) G^T diag(dX/dV1) G (the tube is the model's only part: no offset)."""
        dX = self.pressures(pt)[1]
        vals = (0.5 * pt.h * self.A * self.A) * self._jsign * dX[self._jpar]
        return sp.csc_matrix((vals, (self._jrows, self._jcols)), shape=(self.nz, self.nz))

    def work(self, pt):
        """Viscous work W_k = -Q_k (V_k^{n+1} - V_k^n) >= 0 done on each parcel over the step."""
        _, _, Q, V0, V1 = self.pressures(pt)
        return -Q * (V1 - V0)

    def after_step(self, pt):
        """Heat each parcel by its viscous work: E_k(V^{n+1}, S_k') = E_k(V^{n+1}, S_k) + W_k."""
        t = self.tube
        _, _, Q, V0, V1 = self.pressures(pt)
        W = np.maximum(-Q * (V1 - V0), 0.0)  # Q > 0 only where V1 < V0: W >= 0 (the max guards round-off)
        t.S[:] = heated_entropy(t.S, V1, self._K(), W, self.gamma, self.cv)
        self.last_work = float(np.sum(W))
