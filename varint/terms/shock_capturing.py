"""Shock capturing in the straight tube: an artificial viscous pressure by the discrete Lagrange–d'Alembert
principle, the heating it causes, and an energy-exact pressure (docs/theory.md, "Shock capturing").

The conservative scheme (docs/theory.md §4) cannot carry a shock: the midpoint rule has no way to turn
kinetic energy into heat, so a steepening wave rings.  Scene section ``[shock_capturing]`` adds one
non-conservative force (a :class:`varint.terms.forces.Force`) that does three things:

1. **Viscous pressure** (von Neumann & Richtmyer, J. Appl. Phys. 21, 232 (1950); the linear term of
   Landshoff, LANL report LA-1430 (1955)), in compression only:

       Q_k = rho_k (c_Q^2 du_k^2 + c_L c_k |du_k|)   if du_k < 0,  else 0,
       du_k = (V_k^{n+1} - V_k^n) / (A_k h),

   the jump of the step's mean label velocity across parcel k at cross-section A_k (the tube's, or in a
   swelling tube the parcel's mean cross-section at level n, V_k^n / (s_{k+1}^n - s_k^n)), with
   rho_k = m_k / Vbar_k and the sound speed c_k at the step's midpoint volume Vbar_k = (V_k^n + V_k^{n+1}) / 2.
   Optionally (``limiter``) Q_k is multiplied by 1 - psi_k, Christensen's monotonic limiter of the
   neighbours' du (:func:`limited`): smooth compressions are then not viscous.
2. **Mean-value pressure.**  The midpoint pressure p(V_k(z_mid)) is replaced by the discrete gradient
   Ptilde_k = -(E_k(V_k^{n+1}) - E_k(V_k^n)) / (V_k^{n+1} - V_k^n) (Gonzalez, J. Nonlinear Sci. 6, 449
   (1996)).  Both Ptilde_k and Q_k act through a discrete gradient of the parcel volume, Gbar_k with
   Gbar_k . (z^{n+1} - z^n) = V_k^{n+1} - V_k^n: the constant dV_k/dz of a rigid uniform tube
   (:class:`ShockCapturing`), the averaged vector field of V_k in its own labels and radii otherwise
   (:class:`SwellingShockCapturing`, :func:`avf_volume_gradients`), where a tube-law wall's energy, not
   quadratic in R, gets its own discrete gradient too.  The kinetic energy then changes by exactly
   sum_k (Ptilde_k + Q_k) dV_k minus the wall's energy change.
3. **Heating** (:meth:`ShockCapturing.after_step`): once a step is accepted each parcel's entropy rises so
   that its internal energy at the new volume grows by the viscous work W_k = -Q_k (V_k^{n+1} - V_k^n) >= 0.

Together: total energy (kinetic of gas and wall, internal, wall elastic, p_ext Vol) is conserved to the
Newton tolerance, the axial momentum of a periodic rigid uniform tube too (the forces are differences of
parcel quantities), and no parcel's entropy decreases.

An ideal gas (the heating has a closed form) with the midpoint scheme in a straight tube: rigid and
uniform, rigid with ``tube.area_table``, or with a dynamic wall (linear law or tube law).  varint.scene.schema
refuses a quasistatic wall (its radii are half-level unknowns) and other fluids in one line; the coupled tube
(``[rod]``) has its own force, varint.coupled_shock_capturing.  Kernels are numba; tests/test_shock_capturing.py checks each one against finite differences,
closed forms or a NumPy reference.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp
from numba import njit

from .forces import Declaration, Force
from ..lattice.parcels import k_locate, k_parcel_gradient, k_parcel_hessian, parcel_derivatives, parcel_volumes

__all__ = ["ShockCapturing", "SwellingShockCapturing", "make_shock_capturing", "avf_volume_gradients",
           "mean_value_pressure", "viscous_pressure", "viscous_pressure_q", "heated_entropy"]

#: below this |V1/V0 - 1| the mean-value pressure's derivative is taken from its Taylor series
_SERIES = 1e-3


@njit(cache=True)
def _mean_value_pressure(V0, V1, K, gamma, P, dP):
    """Ptilde = -(E(V1) - E(V0)) / (V1 - V0) of E(V) = K V^(1-gamma) / (gamma - 1), and dPtilde/dV1 (gamma = 1, a
    linear barotropic law: E(V) = -K log V).

    Written as p0 phi(x), p0 = K V0^-gamma, x = V1/V0 - 1, phi(x) = -expm1((1-gamma) log1p(x)) / ((gamma-1) x)
    (gamma = 1: log1p(x) / x): expm1 and log1p keep phi accurate to round-off down to x -> 0 (phi(0) = 1, the
    pressure at V0 = V1).  dphi/dx has a cancellation near 0 and is then taken from phi's series,
    phi = 1 - g/2 x + g(g+1)/6 x^2 - g(g+1)(g+2)/24 x^3 + g(g+1)(g+2)(g+3)/120 x^4 - ... (the same at g = 1).
    """
    for k in range(V0.shape[0]):
        p0 = K[k] * V0[k] ** (-gamma)
        x = V1[k] / V0[k] - 1.0
        g = gamma
        if x == 0.0:
            phi = 1.0
        elif g == 1.0:
            phi = math.log1p(x) / x
        else:
            phi = -math.expm1((1.0 - g) * math.log1p(x)) / ((g - 1.0) * x)
        if abs(x) < _SERIES:
            c1 = -g / 2.0
            c2 = g * (g + 1.0) / 6.0
            c3 = -g * (g + 1.0) * (g + 2.0) / 24.0
            c4 = g * (g + 1.0) * (g + 2.0) * (g + 3.0) / 120.0
            dphi = c1 + x * (2.0 * c2 + x * (3.0 * c3 + x * 4.0 * c4))
        elif g == 1.0:
            # phi' = [x / (1+x) - log1p(x)] / x^2
            dphi = (x / (1.0 + x) - math.log1p(x)) / (x * x)
        else:
            # phi' = [(g-1) (1+x)^-g x - (1 - (1+x)^(1-g))] / ((g-1) x^2)
            dphi = ((g - 1.0) * (1.0 + x) ** (-g) * x + math.expm1((1.0 - g) * math.log1p(x))) / ((g - 1.0) * x * x)
        P[k] = p0 * phi
        dP[k] = p0 * dphi / V0[k]


@njit(cache=True)
def _heated_entropy(S, V1, K, W, gamma, cv, out):
    """S' with E(V1, S') = E(V1, S) + W for E = K(S) V^(1-gamma)/(gamma-1), K ~ exp(S/cv): S' = S + cv log1p(W/E)."""
    for k in range(S.shape[0]):
        E = K[k] * V1[k] ** (1.0 - gamma) / (gamma - 1.0)
        out[k] = S[k] + cv * math.log1p(W[k] / E)


@njit(cache=True)
def _limiter(du, periodic, psi, dm, d0, dp):
    """Christensen's monotonic limiter psi_k = max(0, min(1, (r_L + r_R)/2, 2 r_L, 2 r_R)), r_L = du_{k-1}/du_k,
    r_R = du_{k+1}/du_k, and its derivatives in du_{k-1}, du_k, du_{k+1}.  Only parcels in compression (du_k < 0)
    are limited; a closed end's missing neighbour takes the other side's ratio."""
    M = du.shape[0]
    for k in range(M):
        psi[k] = 0.0
        dm[k] = 0.0
        d0[k] = 0.0
        dp[k] = 0.0
        u = du[k]
        if u >= 0.0:
            continue
        hasL = periodic or k > 0
        hasR = periodic or k < M - 1
        if not hasL and not hasR:
            continue
        uL = du[(k - 1) % M] if hasL else 0.0
        uR = du[(k + 1) % M] if hasR else 0.0
        rL = uL / u if hasL else uR / u
        rR = uR / u if hasR else uL / u
        # d r / d(du_left), d(du_k), d(du_right) for each ratio (a missing side mirrors the other)
        aL = (1.0 / u, -rL / u, 0.0) if hasL else (0.0, -rL / u, 1.0 / u)
        aR = (0.0, -rR / u, 1.0 / u) if hasR else (1.0 / u, -rR / u, 0.0)
        # candidates of the min: 1, mean, 2 rL, 2 rR (the first smallest wins ties: a.e. derivative)
        best = 1.0
        g = (0.0, 0.0, 0.0)
        mean = 0.5 * (rL + rR)
        if mean < best:
            best = mean
            g = (0.5 * (aL[0] + aR[0]), 0.5 * (aL[1] + aR[1]), 0.5 * (aL[2] + aR[2]))
        if 2.0 * rL < best:
            best = 2.0 * rL
            g = (2.0 * aL[0], 2.0 * aL[1], 2.0 * aL[2])
        if 2.0 * rR < best:
            best = 2.0 * rR
            g = (2.0 * aR[0], 2.0 * aR[1], 2.0 * aR[2])
        if best <= 0.0:
            continue
        psi[k] = best
        dm[k], d0[k], dp[k] = g


def limited(Q, dQ, V0, V1, A, h, periodic):
    """Q (1 - psi) with Christensen's limiter on du = (V1 - V0)/(A h) (Caramana, Shashkov & Whalen, J. Comput.
    Phys. 144, 70 (1998), §4): (Q', dQ'/dV1_k, dQ'_k/dV1_{k-1}, dQ'_k/dV1_{k+1}).  In a smooth compression the
    neighbours' du are alike, psi -> 1 and Q' -> 0; at a shock the jump stands alone, psi -> 0."""
    A = np.broadcast_to(np.asarray(A, dtype=np.float64), np.shape(V0))
    du = np.ascontiguousarray((V1 - V0) / (A * h))
    M = len(du)
    psi, dm, d0, dp = (np.empty(M) for _ in range(4))
    _limiter(du, bool(periodic), psi, dm, d0, dp)
    ddu = 1.0 / (A * h)  # d du_j / d V1_j
    left, right = np.roll(ddu, 1), np.roll(ddu, -1)  # of parcels k-1 and k+1 (a closed end's is not used:
    # _limiter gives no derivative towards a missing neighbour)
    Qn = Q * (1.0 - psi)
    diag = dQ * (1.0 - psi) - Q * d0 * ddu
    lower = -Q * dm * left  # d Q'_k / d V1_{k-1}
    upper = -Q * dp * right  # d Q'_k / d V1_{k+1}
    return Qn, diag, lower, upper


def tridiagonal(diag, lower, upper, periodic):
    """The (M, M) sparse matrix with ``diag``, ``lower[k]`` at (k, k-1) and ``upper[k]`` at (k, k+1) (wrapping when periodic)."""
    M = len(diag)
    k = np.arange(M)
    rows, cols, vals = [k], [k], [diag]
    if periodic:
        rows += [k, k]
        cols += [(k - 1) % M, (k + 1) % M]
        vals += [lower, upper]
    else:
        rows += [k[1:], k[:-1]]
        cols += [k[:-1], k[1:]]
        vals += [lower[1:], upper[:-1]]
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(M, M))


def mean_value_pressure(V0, V1, K, gamma):
    """(Ptilde, dPtilde/dV1) per parcel for p = K V^-gamma: an ideal gas (K = exp(S/c_v) m^gamma) or the volume-
    dependent part of a barotropic liquid (``eos.power_law``; its constant part is its own mean value)."""
    V0, V1, K = (np.ascontiguousarray(a, dtype=np.float64) for a in (V0, V1, K))
    P, dP = np.empty_like(V0), np.empty_like(V0)
    _mean_value_pressure(V0, V1, K, float(gamma), P, dP)
    return P, dP


@njit(cache=True)
def _k_viscous_pressure(V0, V1, m, K, gamma, A, h, cQ, cL, Q, dQ):
    """Q_k = rho (c_Q^2 d^2 + c_L c d), d = max(0, -du), du = (V1 - V0)/(A_k h), rho and c at Vbar, and dQ/dV1, on flat
    arrays of one length (:func:`viscous_pressure`)."""
    for k in range(V0.shape[0]):
        du = (V1[k] - V0[k]) / (A[k] * h)
        if du >= 0.0:
            Q[k] = 0.0
            dQ[k] = 0.0
            continue
        d = -du
        dd = -1.0 / (A[k] * h)  # d(d)/dV1: compressing further (V1 smaller) raises d
        Vb = 0.5 * (V0[k] + V1[k])
        rho = m[k] / Vb
        c = math.sqrt(gamma * K[k] * Vb ** (-gamma) / rho)
        drho = -0.5 * rho / Vb  # d rho / dV1 (dVbar/dV1 = 1/2)
        dc = 0.25 * (1.0 - gamma) * c / Vb  # c ~ Vbar^((1-gamma)/2)
        f = cQ * cQ * d * d + cL * c * d
        df = 2.0 * cQ * cQ * d * dd + cL * (dc * d + c * dd)
        Q[k] = rho * f
        dQ[k] = drho * f + rho * df


def viscous_pressure(V0, V1, m, K, gamma, A, h, cQ, cL):
    """(Q, dQ/dV1) per parcel (module docstring, item 1); ``A`` a cross-section, scalar or per parcel.

    ``A`` per parcel: the tube's cross-section (rigid uniform tube) or the parcel's mean cross-section at level n,
    V_k^n / (s_{k+1}^n - s_k^n) (a swelling tube), so that du is the jump of the label velocity that would compress
    the parcel's volume by V1 - V0 at that cross-section."""
    V0, V1, m, K = (np.ascontiguousarray(a, dtype=np.float64) for a in (V0, V1, m, K))
    A = np.ascontiguousarray(np.broadcast_to(np.asarray(A, dtype=np.float64), V0.shape))
    Q, dQ = np.empty_like(V0), np.empty_like(V0)
    _k_viscous_pressure(V0, V1, m, K, float(gamma), A, float(h), float(cQ), float(cL), Q, dQ)
    return Q, dQ


def viscous_pressure_q(V0, V1, m, K, gamma, A, h, cQ, cL):
    """Q of :func:`viscous_pressure`, complex-safe for a complex step through V1 (the energy-momentum step's Jacobian,
    varint/schemes/em_tube.py): Q(V1 + i e) = Q(V1) + i e dQ/dV1 to round-off for the step's e ~ 1e-30, taken from
    the kernel's exact derivative; the branch on Re V1.  The arrays broadcast (a batch of V1)."""
    V1 = np.asarray(V1)
    if any(np.iscomplexobj(a) for a in (V0, m, K, A)):
        raise TypeError("viscous_pressure_q: only V1 may carry a complex step (V0, m, K, A are level-n data)")
    V0, V1, m, K, A = np.broadcast_arrays(V0, V1, m, K, A)
    shape = V1.shape
    Q, dQ = viscous_pressure(np.ravel(V0), np.ravel(np.real(V1)), np.ravel(m), np.ravel(K), gamma, np.ravel(A), h, cQ, cL)
    if np.iscomplexobj(V1):
        return (Q + 1j * np.ravel(np.imag(V1)) * dQ).reshape(shape)
    return Q.reshape(shape)


def heated_entropy(S, V1, K, W, gamma, cv):
    """Entropies after heating each parcel by W >= 0 at volume V1 (module docstring, item 3)."""
    S, V1, K, W = (np.ascontiguousarray(a, dtype=np.float64) for a in (S, V1, K, W))
    out = np.empty_like(S)
    _heated_entropy(S, V1, K, W, float(gamma), float(cv), out)
    return out


def set_viscosity(force, tube, keys):
    """The section's viscosity and the gas on a shock-capturing force (straight or coupled): ``tube``, ``gamma``,
    ``cv``, the coefficients ``cQ``, ``cL``, ``limiter`` (Christensen's on Q, :func:`limited`: off unless the section
    asks for it) and the reference cross-section ``A`` = pi R0^2."""
    eos = tube.eos
    force.tube = tube
    force.gamma, force.cv = eos.gamma, getattr(eos, "cv", None)  # (a barotropic liquid: no entropy, no heating)
    force.cQ, force.cL = float(keys.quadratic), float(keys.linear)
    force.limiter = getattr(keys, "limiter", "none") == "christensen"
    force.A = math.pi * float(tube.R0) ** 2


class ShockCapturing(Force):
    """The ``[shock_capturing]`` force on a :class:`varint.terms.tube.TubePart` (module docstring).

    f^- = f^+ = (h/2) G^T X with X_k = Ptilde_k - p(Vbar_k) + Q_k and G = dV/dz = A D B_s (constant: the
    tube is rigid and uniform; D the parcels' label difference, B_s the labels' selection); its Jacobian (h/2) G^T diag(dX/dV^{n+1}) G is exact.  ``after_step`` heats the
    parcels by the viscous work (``tube.S`` in place: the internal-energy term and the monitors read the
    same array).  ``last_work`` is the viscous work of the last accepted step (sum of W_k, J).
    """

    declaration = Declaration("shock_capturing", {"parcel_entropy": None})

    def __init__(self, tube, keys):
        set_viscosity(self, tube, keys)
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

    def _power_law(self):
        """(c, K) of the parcels' pressure p(V) = c + K V^-gamma (``eos.power_law``)."""
        t = self.tube
        return t.eos.power_law(t.m, getattr(t, "S", None))

    def _K(self):
        return self._power_law()[1]

    def pressures(self, pt):
        """Per parcel at the step ``pt``: (X, dX/dV1, Q, V0, V1) with X = Ptilde - p(Vbar) + Q."""
        V0, V1 = self._volumes(pt.q0, pt.lam), self._volumes(pt.q1, pt.lam)
        K = self._K()
        g = self.gamma
        P, dP = mean_value_pressure(V0, V1, K, g)
        Q, dQ = viscous_pressure(V0, V1, self.tube.m, K, g, self.A, pt.h, self.cQ, self.cL)
        self._off = None
        if self.limiter:
            Q, dQ, lo, up = limited(Q, dQ, V0, V1, self.A, pt.h, self.tube.periodic)
            self._off = (lo, up)  # dQ_k/dV1_{k-1}, dQ_k/dV1_{k+1}: read by jacobian()
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
        J = sp.csc_matrix((vals, (self._jrows, self._jcols)), shape=(self.nz, self.nz))
        if self._off is not None:  # the limiter couples each Q_k to its neighbours' compression
            T = tridiagonal(np.zeros(len(dX)), *self._off, self.tube.periodic)
            G = self._G()
            J = J + sp.csc_matrix(0.5 * pt.h * (G.T @ T @ G))
        return J

    def _G(self):
        """G = dV/dz = A D B_s as a sparse (M, nz) matrix (built once, for the limiter's Jacobian)."""
        if getattr(self, "_Gmat", None) is None:
            t = self.tube
            M = t.M
            D = sp.diags([-np.ones(M), np.ones(M)], [0, 1], shape=(M, M + 1))
            self._Gmat = (self.A * (D @ t.B[: M + 1, :])).tocsr()
        return self._Gmat

    def work(self, pt):
        """Viscous work W_k = -Q_k (V_k^{n+1} - V_k^n) >= 0 done on each parcel over the step."""
        _, _, Q, V0, V1 = self.pressures(pt)
        return -Q * (V1 - V0)

    def after_step(self, pt):
        """Heat each parcel by its viscous work: E_k(V^{n+1}, S_k') = E_k(V^{n+1}, S_k) + W_k."""
        t = self.tube
        if not t.eos.has_entropy:  # a barotropic liquid: only the viscosity-free discrete gradient (§12d), W = 0
            return
        _, _, Q, V0, V1 = self.pressures(pt)
        W = np.maximum(-Q * (V1 - V0), 0.0)  # Q > 0 only where V1 < V0: W >= 0 (the max guards round-off)
        t.S[:] = heated_entropy(t.S, V1, self._K(), W, self.gamma, self.cv)
        self.last_work = float(np.sum(W))


# ---------------------------------------------------------------------------------------------------------
# A swelling tube: the discrete gradient of each parcel volume in its own unknowns (labels and radii)
#
# V_k(s_k, s_{k+1}, R) = int_{s_k}^{s_{k+1}} pi R(x)^2 dx with R piecewise linear between the nodes
# (varint.lattice.parcels) is not linear in its unknowns, so the midpoint gradient no longer gives
# grad V . (z1 - z0) = V1 - V0.  We use the averaged-vector-field discrete gradient (Quispel & McLaren,
# J. Phys. A 41, 045206 (2008); Harten, Lax & van Leer's mean-value form),
#
#     Gbar_k = int_0^1 grad V_k(z0 + tau (z1 - z0)) dtau,   so that  Gbar_k . (z1 - z0) = V_k^{n+1} - V_k^n
#
# exactly (fundamental theorem of calculus), symmetric in the two levels and a second-order approximation
# of grad V_k at the midpoint.  Along the segment V_k is a piecewise polynomial in tau (pieces end where a
# label crosses a node; V is C^1 there, its gradient continuous): on each piece grad V_k has degree <= 4
# in tau and tau * Hess V_k degree <= 4, so three Gauss-Legendre points per piece integrate both exactly.
# Because grad V_k is continuous at the pieces' ends, d Gbar_k / d z1 = int_0^1 tau Hess V_k dtau (the
# moving ends contribute nothing) -- the exact Newton block.  Each parcel's integral involves only its
# own unknowns: s_k, s_{k+1} and the radii of the nodes it covers at either level.

_GAUSS_T = np.array([0.5 - 0.5 * math.sqrt(0.6), 0.5, 0.5 + 0.5 * math.sqrt(0.6)])
_GAUSS_W = np.array([5.0 / 18.0, 8.0 / 18.0, 5.0 / 18.0])


@njit(cache=True)
def _parcel_valid(a0, a1, b0, b1, ds, N, periodic):
    """Both levels of parcel (a, b) finite and in order, and (periodic) within two periods: then every point of
    the segment between them is too, and the kernels stay in their buffers."""
    for x in (a0, a1, b0, b1):
        if not (abs(x / ds) < 2.0 ** 52):
            return False
    if not (b0 > a0 and b1 > a1):
        return False
    return not (periodic and max(b0, b1) - min(a0, a1) > 2.0 * N * ds)


@njit(cache=True)
def _crossings(x0, x1, ds, N, periodic, out, n):
    """Append to ``out`` the tau in (0, 1) where x0 + tau (x1 - x0) crosses a node (an interior one when closed)."""
    if x1 == x0:
        return n
    lo, hi = min(x0, x1), max(x0, x1)
    j = math.floor(lo / ds) + 1
    while j * ds < hi:
        if periodic or 0 < j < N:
            tau = (j * ds - x0) / (x1 - x0)
            if 0.0 < tau < 1.0:
                out[n] = tau
                n += 1
        j += 1
    return n


@njit(cache=True)
def _avf_volume(s0, s1, R0, R1, ds, periodic, nlab, X, want_H, gT, gW,
                grow, gcol, gval, hrow, hcol, hval):
    """Averaged-vector-field gradients Gbar_k of every parcel volume (COO rows k, config columns) and, with
    ``want_H``, sum_k X_k int_0^1 tau Hess V_k dtau (COO in configuration index space).

    Configuration index space as varint.lattice.parcels: label i is column i, node j column nlab + j.  Returns the
    number of G and H entries written (the arrays are sized by the caller from :func:`_avf_sizes`).
    """
    M = s0.shape[0] - 1
    nR = R0.shape[0]
    N = nR if periodic else nR - 1
    taus = np.empty(64)
    Rl = np.empty(1)
    dummy = np.empty(1)
    pg = 0
    ph = 0
    for k in range(M):
        a0, a1, b0, b1 = s0[k], s1[k], s0[k + 1], s1[k + 1]
        if not _parcel_valid(a0, a1, b0, b1, ds, N, periodic):
            # a folded or non-finite parcel (a Newton iterate off the lattice's domain): NaN entries, no
            # out-of-range access; the step then backs off (varint.run.simulation)
            for i in range(4):
                c = k if i == 0 else (k + 1 if i == 1 else nlab + i - 2)
                grow[pg] = k
                gcol[pg] = c
                gval[pg] = np.nan
                pg += 1
                if want_H:
                    for jx in range(4):
                        hrow[ph] = c
                        hcol[ph] = k if jx == 0 else (k + 1 if jx == 1 else nlab + jx - 2)
                        hval[ph] = np.nan
                        ph += 1
            continue
        lo = k_locate(min(a0, a1), ds, nR, periodic)[0]
        hi = k_locate(max(b0, b1), ds, nR, periodic)[0]
        nn = hi - lo + 2  # local nodes lo .. hi + 1
        nloc = 2 + nn
        if Rl.shape[0] < nn:
            Rl = np.empty(2 * nn)
        G = np.zeros(nloc)
        H = np.zeros((nloc, nloc))
        gt = np.empty(nloc)
        Ht = np.empty((nloc, nloc))
        # the pieces of [0, 1]: ends where either label crosses a node
        need = 2 + int(abs(a1 - a0) / ds) + int(abs(b1 - b0) / ds) + 4
        if taus.shape[0] < need:
            taus = np.empty(2 * need)
        taus[0] = 0.0
        n = _crossings(a0, a1, ds, N, periodic, taus, 1)
        n = _crossings(b0, b1, ds, N, periodic, taus, n)
        taus[n] = 1.0
        n += 1
        taus[:n].sort()
        for p in range(n - 1):
            t_lo, t_hi = taus[p], taus[p + 1]
            L = t_hi - t_lo
            if L <= 0.0:
                continue
            for q in range(3):
                tau = t_lo + gT[q] * L
                w = gW[q] * L
                for i in range(nn):
                    j = lo + i
                    jj = j % nR if periodic else j
                    Rl[i] = R0[jj] + tau * (R1[jj] - R0[jj])
                ea, ta, _ = k_locate(a0 + tau * (a1 - a0), ds, nR, periodic)
                eb, tb, _ = k_locate(b0 + tau * (b1 - b0), ds, nR, periodic)
                m = 2 + eb - ea + 2
                gl = gt[:m]
                r0, r1, ra0, rb0, ra1, rb1 = k_parcel_gradient(dummy, Rl, ds, False, k, ea - lo, ta, eb - lo, tb, gl)
                off = ea - lo  # local node of gl[2]
                G[0] += w * gl[0]
                G[1] += w * gl[1]
                for i in range(2, m):
                    G[off + i] += w * gl[i]
                if want_H:
                    Hl = Ht[:m, :m]
                    k_parcel_hessian(ds, ea - lo, ta, eb - lo, tb, r0, r1, ra0, rb0, ra1, rb1, Hl)
                    wt = w * tau
                    for i in range(m):
                        ii = i if i < 2 else off + i
                        for jx in range(m):
                            jj2 = jx if jx < 2 else off + jx
                            H[ii, jj2] += wt * Hl[i, jx]
        for i in range(nloc):
            if i == 0:
                c = k
            elif i == 1:
                c = k + 1
            else:
                j = lo + i - 2
                c = nlab + (j % nR if periodic else j)
            grow[pg] = k
            gcol[pg] = c
            gval[pg] = G[i]
            pg += 1
            if want_H:
                for jx in range(nloc):
                    if jx == 0:
                        c2 = k
                    elif jx == 1:
                        c2 = k + 1
                    else:
                        j = lo + jx - 2
                        c2 = nlab + (j % nR if periodic else j)
                    hrow[ph] = c
                    hcol[ph] = c2
                    hval[ph] = X[k] * H[i, jx]
                    ph += 1
    return pg, ph


@njit(cache=True)
def _avf_sizes(s0, s1, ds, nR, periodic):
    """Number of G and H entries :func:`_avf_volume` writes."""
    M = s0.shape[0] - 1
    N = nR if periodic else nR - 1
    ng = 0
    nh = 0
    for k in range(M):
        if not _parcel_valid(s0[k], s1[k], s0[k + 1], s1[k + 1], ds, N, periodic):
            ng += 4
            nh += 16
            continue
        lo = k_locate(min(s0[k], s1[k]), ds, nR, periodic)[0]
        hi = k_locate(max(s0[k + 1], s1[k + 1]), ds, nR, periodic)[0]
        nloc = 2 + hi - lo + 2
        ng += nloc
        nh += nloc * nloc
    return ng, nh


def _avf_coo(s0, s1, R0, R1, ds, periodic, X):
    s0, s1, R0, R1 = (np.ascontiguousarray(a, dtype=np.float64) for a in (s0, s1, R0, R1))
    nlab, nR = len(s0), len(R0)
    ng, nh = _avf_sizes(s0, s1, float(ds), nR, bool(periodic))
    want_H = X is not None
    if not want_H:
        nh = 0
    Xw = np.ascontiguousarray(X, dtype=np.float64) if want_H else np.zeros(len(s0) - 1)
    grow, gcol, gval = np.empty(ng, np.int64), np.empty(ng, np.int64), np.empty(ng)
    hrow, hcol, hval = np.empty(nh, np.int64), np.empty(nh, np.int64), np.empty(nh)
    _avf_volume(s0, s1, R0, R1, float(ds), bool(periodic), nlab, Xw, want_H, _GAUSS_T, _GAUSS_W,
                grow, gcol, gval, hrow, hcol, hval)
    return (grow, gcol, gval), (hrow, hcol, hval)


def avf_volume_gradients(s0, s1, R0, R1, ds, periodic, X=None):
    """Discrete gradients of the parcel volumes between two configurations (labels s, nodal radii R).

    Returns ``G`` (M, nlab + nR) sparse with ``G @ (c1 - c0) = V(c1) - V(c0)`` row by row (c = concat(s, R)),
    and, with weights ``X`` (M,), ``HX = sum_k X_k d(G_k)/d c1`` (nlab + nR square, sparse): the block the
    Newton Jacobian needs (see the section comment above).
    """
    (grow, gcol, gval), (hrow, hcol, hval) = _avf_coo(s0, s1, R0, R1, ds, periodic, X)
    nlab, n = len(s0), len(s0) + len(R0)
    G = sp.csr_matrix((gval, (grow, gcol)), shape=(nlab - 1, n))
    if X is None:
        return G
    return G, sp.csr_matrix((hval, (hrow, hcol)), shape=(n, n))


#: two Gauss-Legendre points on [0, 1]: exact for the cubic gradient of the tube law's wall energy along a segment
_GAUSS2_T = (0.5 - math.sqrt(3.0) / 6.0, 0.5 + math.sqrt(3.0) / 6.0)


class SwellingShockCapturing(ShockCapturing):
    """``[shock_capturing]`` where the parcel volumes are not linear in the unknowns: a dynamic ``[wall]``
    (linear law or tube law) or a rigid tube of varying cross-section (``tube.area_table``).

    The step's forces, in configuration space and then mapped to the inertial unknowns by the tube's B,
    are f^- = f^+ = (h/2) F with

        F = sum_k (Ptilde_k + Q_k) Gbar_k + grad U_int(z_mid) - [gbar U_wall - grad U_wall(z_mid)],

    Gbar_k the discrete gradient of V_k (:func:`avf_volume_gradients`); the second term cancels the
    internal energy's midpoint force, which the midpoint potential term adds; the third is non-zero only
    for the tube law (its wall energy is a quartic in R, gbar its averaged vector field, exact with two
    Gauss points): the linear wall law, the external pressure's p_ext Vol(R) and gravity are at most
    quadratic, so their midpoint gradient is already a discrete gradient.  With the midpoint kinetic
    term the kinetic energy then changes by F . (z1 - z0) = sum_k (Ptilde_k + Q_k) (V_k^{n+1} - V_k^n)
    - (U_wall^{n+1} - U_wall^n) - (U_ext^{n+1} - U_ext^n), and the heating adds -sum_k Q_k dV_k to the
    internal energy: the total is exact.  Q's compression rate uses the parcel's mean cross-section at
    level n (:func:`viscous_pressure_q`).  The Newton block is exact (tests/test_shock_capturing.py).
    """

    def __init__(self, tube, keys):
        from . import tube_potential as T

        eos = tube.eos
        self.tube = tube
        self.gamma, self.cv = eos.gamma, getattr(eos, "cv", None)
        self.cQ, self.cL = float(keys.quadratic), float(keys.linear)
        self.limiter = getattr(keys, "limiter", "none") == "christensen"
        if tube.nlam:
            raise ValueError("shock capturing: the swelling tube needs every unknown to carry inertia (a dynamic wall)")
        self.nz = tube.nz
        self.nlab = tube.M + 1
        self.Bq = tube.B[:, :tube.nq].tocsr()
        self.BqT = self.Bq.T.tocsr()
        self.internal = next(t for t in tube.terms if isinstance(t, T.InternalEnergy))
        #: wall terms the midpoint rule does not integrate exactly (the tube law); see the class docstring
        self.wall_terms = [t for t in tube.terms if isinstance(t, T.WallTubeLaw)]
        self.last_work = 0.0

    # -- the two levels --------------------------------------------------------------------

    def _cfg(self, q, lam):
        return self.tube.config(np.concatenate([q, lam]))

    def _levels(self, pt):
        t = self.tube
        c0, c1 = self._cfg(pt.q0, pt.lam), self._cfg(pt.q1, pt.lam)
        V0 = parcel_volumes(c0.s, c0.R, t.ds, t.periodic)
        V1 = parcel_volumes(c1.s, c1.R, t.ds, t.periodic)
        return c0, c1, V0, V1

    def pressures(self, pt, levels=None):
        """Per parcel at the step ``pt``: (X, dX/dV1, Q, V0, V1) with X = Ptilde + Q, the pressure that
        multiplies the discrete gradient of V_k (the midpoint pressure is cancelled separately)."""
        c0, c1, V0, V1 = levels if levels is not None else self._levels(pt)
        c, K = self._power_law()
        g = self.gamma
        P, dP = mean_value_pressure(V0, V1, K, g)
        P = P + c  # (a barotropic liquid's constant part is its own mean value)
        A0 = V0 / np.diff(c0.s)  # the parcels' mean cross-section at level n
        Q, dQ = viscous_pressure(V0, V1, self.tube.m, K, g, A0, pt.h, self.cQ, self.cL)
        self._off = None
        if self.limiter:
            Q, dQ, lo, up = limited(Q, dQ, V0, V1, A0, pt.h, self.tube.periodic)
            self._off = (lo, up)
        return P + Q, dP + dQ, Q, V0, V1

    def _path(self, pt, tau):
        if tau == 0.5:  # the midpoint term's own configuration, bit for bit (its internal-energy force is cancelled)
            return self._cfg(0.5 * (pt.q0 + pt.q1), pt.lam)
        return self._cfg(pt.q0 + tau * (pt.q1 - pt.q0), pt.lam)

    # -- Force interface ---------------------------------------------------------------------

    def config_force(self, pt):
        """F of the class docstring in configuration index space (labels, then radii)."""
        t = self.tube
        lv = self._levels(pt)
        c0, c1 = lv[:2]
        X = self.pressures(pt, lv)[0]
        (gr, gc, gv), _ = _avf_coo(c0.s, c1.s, c0.R, c1.R, t.ds, t.periodic, None)
        F = np.bincount(gc, weights=gv * X[gr], minlength=self.nlab + t.nR)  # Gbar^T X
        gs, gR, gmu = np.zeros(self.nlab), np.zeros(t.nR), np.zeros(0)
        cm = self._path(pt, 0.5)
        self.internal.gradient(cm, {}, gs, gR, gmu)
        for term in self.wall_terms:
            ws, wR = np.zeros(self.nlab), np.zeros(t.nR)
            for tau in _GAUSS2_T:
                term.gradient(self._path(pt, tau), {}, ws, wR, gmu)
            wR *= 0.5  # the two Gauss weights
            mR = np.zeros(t.nR)
            term.gradient(cm, {}, np.zeros(self.nlab), mR, gmu)
            gR -= wR - mR
        return F + np.concatenate([gs, gR])

    def add(self, pt, d, level):
        """f^- (level 0) = f^+ (level 1) = (h/2) B_q^T F into the tube's inertial block."""
        d.tube_q += 0.5 * pt.h * (self.BqT @ self.config_force(pt))

    def jacobian(self, pt):
        """d f^- / dz = (h/2) B_q^T [Gbar^T diag(dX/dV1) grad V(z1) + sum_k X_k dGbar_k/dz1 + H_int(z_mid)/2
        - (int tau H_wall dtau - H_wall(z_mid)/2)] B_q, every piece exact."""
        t = self.tube
        lv = self._levels(pt)
        c0, c1 = lv[:2]
        X, dX = self.pressures(pt, lv)[:2]
        G, HX = avf_volume_gradients(c0.s, c1.s, c0.R, c1.R, t.ds, t.periodic, X)
        M = t.M
        zero = np.zeros(M)
        jr, jc, jv = parcel_derivatives(c1.s, c1.R, t.ds, t.periodic, zero, zero, True, True)[3]
        n = self.nlab + t.nR
        J1 = sp.csr_matrix((jv, (jr, jc)), shape=(M, n))
        D = sp.diags(dX) if self._off is None else tridiagonal(dX, *self._off, t.periodic)
        A = G.T @ D @ J1 + HX
        cm = self._path(pt, 0.5)
        r, c, v = self.internal.hessian(cm, {}, t.index)
        A = A + sp.csr_matrix((0.5 * v, (r, c)), shape=(n, n))
        for term in self.wall_terms:
            for tau in _GAUSS2_T:
                r, c, v = term.hessian(self._path(pt, tau), {}, t.index)
                A = A - sp.csr_matrix((0.5 * tau * v, (r, c)), shape=(n, n))
            r, c, v = term.hessian(cm, {}, t.index)
            A = A + sp.csr_matrix((0.5 * v, (r, c)), shape=(n, n))
        return sp.csc_matrix(0.5 * pt.h * (self.BqT @ A @ self.Bq))


def make_shock_capturing(tube, keys):
    """The ``[shock_capturing]`` force for ``tube``: the rigid uniform tube's (linear volumes) or the swelling one's."""
    if not tube.has_wall and tube.scene.tube.area_table is None:
        return ShockCapturing(tube, keys)
    return SwellingShockCapturing(tube, keys)
