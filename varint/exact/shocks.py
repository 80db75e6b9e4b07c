"""Shock waves in the tube: jump conditions, the exact Riemann solver, the traveling shock.

Pure functions, independent of the stepper (docs/theory.md §11).  Equation labels in ``code font``
are the ``\\label{}`` names in F. Gay-Balmaz & V. Putkaradze, *Geometric theory of flexible and
expandable tubes conveying fluid: equations, solutions and shock waves*.

* Rankine–Hugoniot: :func:`rh_residuals` (the paper's ``RH_mass``, ``RH_momentum``, ``RH_energy``
  for any tube state), :func:`rh_classical` (``RH_mass_0`` … ``RH_energy_0``), :func:`rh_moving`
  (``RH_moving``, ``RH_moving_perfect``); the jumps across a shock captured in a run file are measured by
  ``varint.analysis.shock_measure``.
* :class:`RiemannSolution`: the exact solution of the Riemann problem of the 1-D Euler equations of
  an ideal gas (E. F. Toro, *Riemann Solvers and Numerical Methods for Fluid Dynamics*, ch. 4), the
  rigid uniform tube.
* :func:`traveling_shock`: the traveling wave of ``Q_cons_wave``, ``meq2_wave``, ``Req_wave`` with a
  shock, in the straight tube with the linear wall law (``beta_1_2``), for a given speed;
  :func:`traveling_shock_of_strength`, :func:`speed_range`, :func:`classical_mach`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from ..errors import VarintError

__all__ = ["TubeState", "ideal_gas_state", "rh_residuals", "rh_classical", "rh_moving", "relative_residuals",
           "RiemannSolution", "ShockError", "TravelingShock", "traveling_shock",
           "traveling_shock_of_strength", "speed_range", "classical_mach", "classical_shock",
           "far_state_behind", "make_tube"]

E1 = np.array([1.0, 0.0, 0.0])


class ShockError(VarintError):
    """A traveling shock asked for outside its admissible range, or a run file without a shock."""


# ---------------------------------------------------------------------------------------------------
# Rankine–Hugoniot


@dataclass(frozen=True)
class TubeState:
    """The fluid and tube state on one side of a shock (SI).

    ``rho`` density, ``u`` fluid velocity along the tube (``u`` of the paper: ``gamma + Gamma u`` is
    the fluid velocity in the body frame), ``p`` pressure, ``e`` specific internal energy,
    ``Q = A |Gamma|`` the cross-section measure of the paper (``xi = rho Q``), ``Gamma`` and ``gam``
    the tube's convected strain and linear velocity (3-vectors; straight tube at rest:
    ``Gamma = E1``, ``gam = 0``).
    """

    rho: float
    u: float
    p: float
    e: float
    Q: float = 1.0
    Gamma: tuple = (1.0, 0.0, 0.0)
    gam: tuple = (0.0, 0.0, 0.0)


def ideal_gas_state(rho, u, p, gamma, R=None, Gamma=(1.0, 0.0, 0.0), gam=(0.0, 0.0, 0.0)):
    """A :class:`TubeState` of a perfect gas, ``e = p / ((gamma - 1) rho)``; ``Q = pi R^2 |Gamma|`` (1 without R)."""
    G = np.asarray(Gamma, dtype=float)
    Q = 1.0 if R is None else math.pi * R * R * float(np.linalg.norm(G))
    return TubeState(float(rho), float(u), float(p), float(p) / ((gamma - 1.0) * float(rho)), Q, tuple(G), tuple(gam))


def _fluxes(s):
    """Densities and fluxes of ``RH_mass``, ``RH_momentum``, ``RH_energy`` (the forms with ``xi = rho Q``)."""
    G, g = np.asarray(s.Gamma, float), np.asarray(s.gam, float)
    xi = s.rho * s.Q
    v = g + G * s.u                    # fluid velocity in the body frame
    Gv = float(G @ v)
    G2 = float(G @ G)
    dens = (xi, xi * Gv, xi * (s.e + 0.5 * float(v @ v)))
    flux = (xi * s.u, xi * s.u * Gv + s.Q * s.p,
            0.5 * xi * s.u * float(v @ v) + s.p * xi / (s.rho * G2) * Gv + xi * s.u * s.e)
    return dens, flux


def rh_residuals(left, right, c):
    """The paper's generalised jump conditions (``RH_mass``, ``RH_momentum``, ``RH_energy``).

    ``left``, ``right``: :class:`TubeState` on either side; ``c`` the shock speed. Returns
    ``{"mass", "momentum", "energy"}``: each ``c [density] - [flux]`` with ``[a] = a_right - a_left``
    (zero when the condition holds), and ``"scale"``: for each condition the largest of
    ``|c [density]|``, ``|[flux]|`` and the flux magnitudes, to make them relative
    (:func:`relative_residuals`).
    """
    dl, fl = _fluxes(left)
    dr, fr = _fluxes(right)
    names = ("mass", "momentum", "energy")
    out = {n: c * (dr[i] - dl[i]) - (fr[i] - fl[i]) for i, n in enumerate(names)}
    out["scale"] = {n: max(abs(c * (dr[i] - dl[i])), abs(fr[i] - fl[i]), 1e-300) for i, n in enumerate(names)}
    return out


def relative_residuals(res):
    """``{"mass", "momentum", "energy"}`` of :func:`rh_residuals` divided by their scales (jump sizes)."""
    return {n: abs(res[n]) / res["scale"][n] for n in ("mass", "momentum", "energy")}


def rh_classical(left, right, c):
    """The classical conditions ``RH_mass_0``, ``RH_momentum_0``, ``RH_energy_0`` (straight rigid tube at rest).

    ``left``, ``right``: :class:`TubeState` (only rho, u, p, e are read); returns
    ``{"mass", "momentum", "energy"}`` as ``c [density] - [flux]``.
    """
    def dens(s):
        return s.rho, s.rho * s.u, 0.5 * s.rho * s.u ** 2 + s.rho * s.e

    def flux(s):
        return s.rho * s.u, s.rho * s.u ** 2 + s.p, (0.5 * s.rho * s.u ** 2 + s.rho * s.e + s.p) * s.u

    dl, dr, fl, fr = dens(left), dens(right), flux(left), flux(right)
    return {n: c * (dr[i] - dl[i]) - (fr[i] - fl[i]) for i, n in enumerate(("mass", "momentum", "energy"))}


def rh_moving(left, right, c, gamma=None):
    """``RH_moving`` (or ``RH_moving_perfect`` with the ratio of specific heats ``gamma``): traveling waves.

    For a tube moving as a traveling wave, ``gam = -c (Gamma - E1)``; ``Gamma`` is continuous across the
    shock and is read from ``left``.  Returns ``{"mass", "momentum", "energy"}``: the jumps
    ``[rho (u - c)]``, ``[rho (u-c)^2 |Gamma|^2 + rho (u-c) c Gamma.E1 + p]`` and the energy bracket,
    with ``p`` replaced by ``(gamma - 1) rho e`` when ``gamma`` is given.
    """
    G = np.asarray(left.Gamma, float)
    G2, G1 = float(G @ G), float(G @ E1)

    def parts(s):
        w = s.u - c
        p = s.p if gamma is None else (gamma - 1.0) * s.rho * s.e
        mom = s.rho * w * w * G2 + s.rho * w * c * G1 + p
        en = (s.rho * s.e * w + 0.5 * s.rho * w * (c * c + 2 * w * c * G1 + w * w * G2)
              + p / G2 * (G2 * w + c * G1))
        return s.rho * w, mom, en

    a, b = parts(left), parts(right)
    return {n: b[i] - a[i] for i, n in enumerate(("mass", "momentum", "energy"))}


# ---------------------------------------------------------------------------------------------------
# The exact Riemann solver (Toro, ch. 4)


class RiemannSolution:
    """Exact solution of the Riemann problem for the 1-D Euler equations of an ideal gas.

    ``left``, ``right``: (rho, u, p) either side of ``x0`` at ``t = 0``; ``gamma`` the ratio of specific
    heats.  The star pressure solves Toro's pressure function f(p) = f_L(p) + f_R(p) + u_R - u_L = 0
    (eqs. 4.5–4.7) by Newton's method from the two-rarefaction guess, to round-off; ``p_star``,
    ``u_star``, ``rho_star_left``, ``rho_star_right`` and the wave types (``"shock"`` or
    ``"rarefaction"``) are attributes; :meth:`sample` gives rho, u, p at (x, t) (Toro §4.5).
    Raises :class:`~varint.VarintError` when the data generate vacuum (pressure positivity condition, eq. 4.40).
    """

    def __init__(self, left, right, gamma=1.4):
        self.gamma = g = float(gamma)
        self.left = tuple(float(v) for v in left)
        self.right = tuple(float(v) for v in right)
        rl, ul, pl = self.left
        rr, ur, pr = self.right
        if min(rl, pl, rr, pr) <= 0:
            raise VarintError("riemann: densities and pressures must be positive")
        self.cl, self.cr = math.sqrt(g * pl / rl), math.sqrt(g * pr / rr)
        if 2.0 / (g - 1.0) * (self.cl + self.cr) <= ur - ul:
            raise VarintError("riemann: the initial data generate vacuum (pressure positivity condition violated)")
        self.p_star, self.u_star = self._star()
        ps = self.p_star
        self.rho_star_left = self._rho_star(rl, pl, ps)
        self.rho_star_right = self._rho_star(rr, pr, ps)
        self.left_wave = "shock" if ps > pl else "rarefaction"
        self.right_wave = "shock" if ps > pr else "rarefaction"

    def _f(self, p, rho, pk, ck):
        """Toro eq. 4.6/4.7: the function f_K and its derivative."""
        g = self.gamma
        if p > pk:
            A, B = 2.0 / ((g + 1.0) * rho), (g - 1.0) / (g + 1.0) * pk
            q = math.sqrt(A / (p + B))
            return (p - pk) * q, q * (1.0 - 0.5 * (p - pk) / (B + p))
        r = p / pk
        return 2.0 * ck / (g - 1.0) * (r ** ((g - 1.0) / (2 * g)) - 1.0), r ** (-(g + 1.0) / (2 * g)) / (rho * ck)

    def _star(self):
        g = self.gamma
        rl, ul, pl = self.left
        rr, ur, pr = self.right
        du = ur - ul
        z = (g - 1.0) / (2 * g)
        # two-rarefaction guess (Toro eq. 4.46): exact when both waves are rarefactions
        p = ((self.cl + self.cr - 0.5 * (g - 1.0) * du) / (self.cl / pl ** z + self.cr / pr ** z)) ** (1.0 / z)
        p = max(p, 1e-14 * min(pl, pr))
        for _ in range(100):
            fl, dl = self._f(p, rl, pl, self.cl)
            fr, dr = self._f(p, rr, pr, self.cr)
            dp = (fl + fr + du) / (dl + dr)
            pn = p - dp
            if pn <= 0:
                pn = 0.5 * p
            if abs(pn - p) <= 4e-16 * (pn + p):
                p = pn
                break
            p = pn
        fl, _ = self._f(p, rl, pl, self.cl)
        fr, _ = self._f(p, rr, pr, self.cr)
        return p, 0.5 * (ul + ur) + 0.5 * (fr - fl)

    def _rho_star(self, rho, pk, ps):
        g = self.gamma
        if ps > pk:  # Toro eq. 4.50 / 4.57
            r = ps / pk
            gm = (g - 1.0) / (g + 1.0)
            return rho * (r + gm) / (gm * r + 1.0)
        return rho * (ps / pk) ** (1.0 / g)  # isentropic, eq. 4.53 / 4.60

    def shock_speeds(self):
        """(S_L, S_R): speeds of the left and right waves when they are shocks (None otherwise), Toro eqs. 4.52, 4.59."""
        g = self.gamma
        out = []
        for (rho, u, pk), ck, sign, kind in ((self.left, self.cl, -1, self.left_wave), (self.right, self.cr, 1, self.right_wave)):
            if kind != "shock":
                out.append(None)
                continue
            out.append(u + sign * ck * math.sqrt((g + 1.0) / (2 * g) * self.p_star / pk + (g - 1.0) / (2 * g)))
        return tuple(out)

    def sample(self, x, t, x0=0.0):
        """rho, u, p (arrays) at positions ``x`` and time ``t > 0`` (Toro §4.5, Fig. 4.14)."""
        x = np.asarray(x, dtype=float)
        xi = (x - x0) / t
        g = self.gamma
        rl, ul, pl = self.left
        rr, ur, pr = self.right
        ps, us = self.p_star, self.u_star
        rho, u, p = np.empty_like(xi), np.empty_like(xi), np.empty_like(xi)
        SL, SR = self.shock_speeds()
        left_of_contact = xi <= us
        # -- left side
        m = left_of_contact
        if self.left_wave == "shock":
            a = m & (xi < SL)
            b = m & ~(xi < SL)
            rho[a], u[a], p[a] = rl, ul, pl
            rho[b], u[b], p[b] = self.rho_star_left, us, ps
        else:
            cs = self.cl * (ps / pl) ** ((g - 1.0) / (2 * g))
            head, tail = ul - self.cl, us - cs
            a = m & (xi < head)
            b = m & (xi >= tail)
            f = m & ~(xi < head) & ~(xi >= tail)
            rho[a], u[a], p[a] = rl, ul, pl
            rho[b], u[b], p[b] = self.rho_star_left, us, ps
            k = 2.0 / (g + 1.0) + (g - 1.0) / ((g + 1.0) * self.cl) * (ul - xi[f])
            rho[f] = rl * k ** (2.0 / (g - 1.0))
            u[f] = 2.0 / (g + 1.0) * (self.cl + 0.5 * (g - 1.0) * ul + xi[f])
            p[f] = pl * k ** (2 * g / (g - 1.0))
        # -- right side
        m = ~left_of_contact
        if self.right_wave == "shock":
            a = m & (xi > SR)
            b = m & ~(xi > SR)
            rho[a], u[a], p[a] = rr, ur, pr
            rho[b], u[b], p[b] = self.rho_star_right, us, ps
        else:
            cs = self.cr * (ps / pr) ** ((g - 1.0) / (2 * g))
            head, tail = ur + self.cr, us + cs
            a = m & (xi > head)
            b = m & (xi <= tail)
            f = m & ~(xi > head) & ~(xi <= tail)
            rho[a], u[a], p[a] = rr, ur, pr
            rho[b], u[b], p[b] = self.rho_star_right, us, ps
            k = 2.0 / (g + 1.0) - (g - 1.0) / ((g + 1.0) * self.cr) * (ur - xi[f])
            rho[f] = rr * k ** (2.0 / (g - 1.0))
            u[f] = 2.0 / (g + 1.0) * (-self.cr + 0.5 * (g - 1.0) * ur + xi[f])
            p[f] = pr * k ** (2 * g / (g - 1.0))
        return rho, u, p


# ---------------------------------------------------------------------------------------------------
# Measuring a captured shock in a run file


# ---------------------------------------------------------------------------------------------------
# The traveling shock in the expandable tube (paper §"Traveling wave solutions")


def classical_mach(z, gamma):
    """Mach number of a normal shock of strength ``z = (p_+ - p_-)/p_-``: sqrt(1 + (gamma+1) z / (2 gamma))."""
    return np.sqrt(1.0 + (gamma + 1.0) * np.asarray(z, dtype=float) / (2.0 * gamma))


def classical_shock(rho, p, M, gamma):
    """Normal shock into gas at rest (rho, p) at Mach ``M``: (rho_behind, u_behind, p_behind) in the lab frame."""
    c = M * math.sqrt(gamma * p / rho)
    p2 = p * (1.0 + 2 * gamma / (gamma + 1.0) * (M * M - 1.0))
    rho2 = rho * (gamma + 1.0) * M * M / ((gamma - 1.0) * M * M + 2.0)
    return rho2, c * (1.0 - rho / rho2), p2


@dataclass(frozen=True)
class _Tube:
    """Tube, linear wall law and gas at rest ahead (SI)."""

    R0: float          # reference radius of the wall law
    beta1: float
    beta2: float
    a: float
    p_ext: float
    rho: float         # gas ahead
    p: float
    gamma: float

    @property
    def R_ahead(self):
        """Equilibrium radius of the wall with the gas ahead: beta2 (R - R0) = 2 pi R (p - p_ext)."""
        d = self.p - self.p_ext
        return self.beta2 * self.R0 / (self.beta2 - 2 * math.pi * d)


@dataclass
class TravelingShock:
    """A traveling shock in the straight expandable tube (see :func:`traveling_shock`).

    Attributes (SI): ``speed`` c; the far state behind ``p_plus``, ``R_plus``, ``u_plus``, ``rho_plus``;
    the state ahead ``p_minus``, ``R_minus``, ``rho_minus`` (at rest); ``R_shock`` the radius at the shock;
    ``ahead``/``behind`` the (rho, u, p) immediately either side of the shock; ``strength``
    z = (p_plus - p_minus)/p_minus; ``mach`` c / c_s ahead; ``kappa_minus``, ``kappa_plus`` (p / rho^gamma
    either side, the entropy through S = c_v ln kappa).
    """

    speed: float
    tube: _Tube
    p_plus: float
    R_plus: float
    u_plus: float
    rho_plus: float
    R_shock: float
    kappa_minus: float
    kappa_plus: float
    ahead: tuple
    behind: tuple
    _tables: dict = field(default_factory=dict, repr=False)

    @property
    def p_minus(self):
        return self.tube.p

    @property
    def rho_minus(self):
        return self.tube.rho

    @property
    def R_minus(self):
        return self.tube.R_ahead

    @property
    def strength(self):
        return (self.p_plus - self.tube.p) / self.tube.p

    @property
    def mach(self):
        return self.speed / math.sqrt(self.tube.gamma * self.tube.p / self.tube.rho)

    def as_dict(self):
        """The JSON of ``varint shock``: speed, far state behind, shock radius and the state ahead."""
        return {"speed": self.speed, "p_plus": self.p_plus, "R_plus": self.R_plus, "u_plus": self.u_plus,
                "rho_plus": self.rho_plus, "R_shock": self.R_shock, "strength": self.strength, "mach": self.mach,
                "p_minus": self.p_minus, "R_minus": self.R_minus, "rho_minus": self.rho_minus,
                "p_shock_ahead": self.ahead[2], "p_shock_behind": self.behind[2],
                "speed_range": list(speed_range_of(self.tube))}

    # -- the smooth parts
    def _side(self, behind):
        return (self.kappa_plus, "subsonic") if behind else (self.kappa_minus, "supersonic")

    def state_at(self, R, behind):
        """(rho, u, p) on one smooth side of the shock at radius R (``Q_cons_wave``, ``meq2_wave``)."""
        kappa, branch = self._side(behind)
        rho = _branch_density(self.tube, self.speed, kappa, R, branch)
        w = _mass_flux(self.tube, self.speed) / (rho * math.pi * R * R)
        return rho, self.speed + w, kappa * rho ** self.tube.gamma

    def _table(self, behind, span):
        key = (behind, span)
        if key in self._tables:
            return self._tables[key]
        tb, c = self.tube, self.speed
        K = tb.beta1 - tb.a * c * c
        kappa, branch = self._side(behind)
        Rf = self.R_plus if behind else self.R_minus

        def Phi(R):
            rho = _branch_density(tb, c, kappa, R, branch)
            return _phi(tb, c, kappa, rho, R)

        def rhs(x, y):
            # the far state is a saddle of Req_wave: stop there rather than cross it on round-off
            if (behind and y[0] >= Rf) or (not behind and y[0] <= Rf):
                return [0.0]
            return [-math.sqrt(max(2.0 * Phi(y[0]) / K, 0.0))]

        # integrate away from the shock; the far state is approached exponentially
        xs = -span if behind else span
        sol = solve_ivp(rhs, (0.0, xs), [self.R_shock], method="DOP853", rtol=1e-11, atol=1e-14 * tb.R0,
                        dense_output=True)
        if not sol.success:  # pragma: no cover - the integrand is smooth
            raise ShockError(f"traveling shock: profile integration failed ({sol.message})")
        self._tables[key] = sol.sol
        return sol.sol

    def profile(self, x):
        """R, rho, u, p at ``x = s - c t - x_shock`` (arrays); the shock at x = 0, the gas at rest for x > 0 far ahead.

        R and R' are continuous at x = 0; rho, u, p jump there (x = 0 belongs to the state behind).
        """
        x = np.asarray(x, dtype=float)
        R, rho, u, p = (np.empty_like(x) for _ in range(4))
        span = max(float(np.max(np.abs(x))) if x.size else 0.0, 1e-12)
        span = 2.0 ** math.ceil(math.log2(span)) if span > 0 else 1.0
        for behind, mask in ((True, x <= 0), (False, x > 0)):
            if not np.any(mask):
                continue
            sol = self._table(behind, span)
            R[mask] = sol(x[mask])[0]
            for j in np.flatnonzero(mask):
                rho[j], u[j], p[j] = self.state_at(R[j], behind)
        return R, rho, u, p

    def wall_velocity(self, x):
        """dR/dt = -c dR/dx of the traveling wall at ``x`` (``x`` as in :meth:`profile`)."""
        x = np.asarray(x, dtype=float)
        R = self.profile(x)[0]
        K = self.tube.beta1 - self.tube.a * self.speed ** 2
        out = np.empty_like(x)
        for j in range(x.size):
            behind = x.flat[j] <= 0
            kappa, branch = self._side(behind)
            rho = _branch_density(self.tube, self.speed, kappa, R.flat[j], branch)
            out.flat[j] = self.speed * math.sqrt(max(2.0 * _phi(self.tube, self.speed, kappa, rho, R.flat[j]) / K, 0.0))
        return out


def _mass_flux(tb, c):
    """rho (u - c) A, the same everywhere in the wave (``Q_cons_wave``): -rho_- c pi R_-^2."""
    return -tb.rho * c * math.pi * tb.R_ahead ** 2


def _bernoulli(tb, c):
    """h + (u - c)^2 / 2, the same everywhere (``meq2_wave``, and across the shock by ``RH_energy``)."""
    return tb.gamma / (tb.gamma - 1.0) * tb.p / tb.rho + 0.5 * c * c


def _branch_density(tb, c, kappa, R, branch):
    """Density at radius R on the isentrope p = kappa rho^gamma with the wave's mass flux and Bernoulli constant.

    ``branch`` "supersonic" (|u - c| > c_s, ahead of the shock) or "subsonic" (behind).
    """
    g = tb.gamma
    A = math.pi * R * R
    j = _mass_flux(tb, c) / A          # rho w
    B = _bernoulli(tb, c)

    def f(rho):
        return g / (g - 1.0) * kappa * rho ** (g - 1.0) + 0.5 * j * j / (rho * rho) - B

    rs = (j * j / (g * kappa)) ** (1.0 / (g + 1.0))  # sonic density
    if f(rs) > 0:
        raise ShockError(f"traveling shock: the flow chokes at R = {R:.6g} m (no {branch} state)")
    if branch == "supersonic":
        lo = 0.5 * abs(j) / math.sqrt(2 * B)
        while f(lo) <= 0:
            lo *= 0.5
        return brentq(f, lo, rs, xtol=1e-300, rtol=1e-15, maxiter=400)
    hi = ((g - 1.0) * B / (g * kappa)) ** (1.0 / (g - 1.0)) * 1.0001
    while f(hi) <= 0:
        hi *= 2.0
    return brentq(f, rs, hi, xtol=1e-300, rtol=1e-15, maxiter=400)


def _phi(tb, c, kappa, rho, R):
    """(beta1 - a c^2) R'^2 / 2 on a smooth side: the first integral of ``Req_wave`` (docs/theory.md §11).

    I = m u + (p - p_ext) A - beta2 (R - R0)^2 / 2 + (beta1 - a c^2) R'^2 / 2 is the same everywhere in the
    wave, across the shock too (``RH_momentum`` with R, R' continuous); this returns
    I_ahead - m u - (p - p_ext) A + beta2 (R - R0)^2 / 2 at the state (kappa, rho) of radius R.
    """
    m = _mass_flux(tb, c)
    A = math.pi * R * R
    u = c + m / (rho * A)
    p = kappa * rho ** tb.gamma
    return _I_ahead(tb) - m * u - (p - tb.p_ext) * A + 0.5 * tb.beta2 * (R - tb.R0) ** 2


def _I_ahead(tb):
    Rm = tb.R_ahead
    return (tb.p - tb.p_ext) * math.pi * Rm * Rm - 0.5 * tb.beta2 * (Rm - tb.R0) ** 2


def _far_residual(tb, c, Rp):
    """Energy (Bernoulli) residual of the far state behind with radius Rp, and that state (rho, u, p).

    Mass (``Q_cons_wave``), the momentum integral I (u_+ from it) and the wall at rest
    (``Req_wave`` with R' = R'' = 0: beta2 (R - R0) = 2 pi R (p - p_ext)) fix u_+, p_+, rho_+ for a given
    R_+; the Bernoulli constant (``meq2_wave``, ``RH_energy``) is the remaining equation.
    """
    Rm = tb.R_ahead
    up = tb.beta2 * tb.R0 * (Rp - Rm) / (2 * math.pi * tb.rho * c * Rm * Rm)
    pp = tb.p_ext + tb.beta2 * (Rp - tb.R0) / (2 * math.pi * Rp)
    if up >= c or pp <= 0:
        return math.nan, None
    rhop = tb.rho * c * Rm * Rm / ((c - up) * Rp * Rp)
    g = tb.gamma
    r = g / (g - 1.0) * pp / rhop + 0.5 * (up - c) ** 2 - _bernoulli(tb, c)
    return r / _bernoulli(tb, c), (rhop, up, pp)


def far_state_behind(tb, c):
    """The far state behind a traveling shock of speed c: ``(R_+, rho_+, u_+, p_+)``, or None if there is none.

    Solves mass, energy, the momentum integral and the wall equilibrium (docs/theory.md §11) for the
    non-trivial ``R_+ > R_-`` (``R_+ = R_-`` is the gas at rest).  The residual is scanned on a geometric grid
    of ``R_+ - R_-`` up to the radius where the wall's pressure ``p_+`` would make ``u_+`` reach c.
    """
    Rm = tb.R_ahead
    # the largest admissible R_+: u_+ < c
    Rmax = Rm + 2 * math.pi * tb.rho * c * c * Rm * Rm / (tb.beta2 * tb.R0)
    d = Rm * np.geomspace(1e-9, (Rmax - Rm) / Rm * (1 - 1e-12), 400)
    f = np.array([_far_residual(tb, c, Rm + di)[0] for di in d])
    ok = np.isfinite(f)
    idx = [k for k in range(len(d) - 1) if ok[k] and ok[k + 1] and f[k] * f[k + 1] < 0]
    if not idx:
        return None
    k = idx[0]
    Rp = brentq(lambda R: _far_residual(tb, c, R)[0], Rm + d[k], Rm + d[k + 1], xtol=1e-300, rtol=1e-15, maxiter=400)
    rhop, up, pp = _far_residual(tb, c, Rp)[1]
    return Rp, rhop, up, pp


def _normal_shock_kappa(tb, c, R):
    """kappa = p / rho^gamma behind the gas-dynamic shock whose upstream is the supersonic state at radius R."""
    g = tb.gamma
    kappa_m = tb.p / tb.rho ** g
    rho1 = _branch_density(tb, c, kappa_m, R, "supersonic")
    p1 = kappa_m * rho1 ** g
    w1 = _mass_flux(tb, c) / (rho1 * math.pi * R * R)
    M2 = w1 * w1 * rho1 / (g * p1)
    p2 = p1 * (1.0 + 2 * g / (g + 1.0) * (M2 - 1.0))
    rho2 = rho1 * (g + 1.0) * M2 / ((g - 1.0) * M2 + 2.0)
    return p2 / rho2 ** g, (rho1, c + w1, p1), (rho2, c + w1 * rho1 / rho2, p2)


def _check_speed(tb, c):
    cs = math.sqrt(tb.gamma * tb.p / tb.rho)
    if not c > cs:
        raise ShockError(f"speed {c:g} m/s: a shock must be faster than the sound speed ahead, {cs:.6g} m/s "
                         f"(admissible range {_range_text(tb)})")
    if tb.a > 0 and not tb.a * c * c < tb.beta1:
        raise ShockError(f"speed {c:g} m/s: not below c* = sqrt(beta1/a) = {math.sqrt(tb.beta1 / tb.a):.6g} m/s, "
                         f"where the wall equation of the wave changes type and no monotone profile exists "
                         f"(admissible range {_range_text(tb)})")


def _solve(tb, c):
    """The traveling shock of speed c, or a ShockError naming why it does not exist."""
    _check_speed(tb, c)
    far = far_state_behind(tb, c)
    if far is None:
        raise ShockError(f"speed {c:g} m/s: no far state behind the shock (admissible range {_range_text(tb)})")
    Rp, rhop, up, pp = far
    g = tb.gamma
    kappa_m = tb.p / tb.rho ** g
    kappa_p = pp / rhop ** g
    Rm = tb.R_ahead
    if not kappa_p > kappa_m:
        raise ShockError(f"speed {c:g} m/s: the far state behind has less entropy than the gas ahead "
                         f"(admissible range {_range_text(tb)})")

    def mismatch(R):
        return math.log(_normal_shock_kappa(tb, c, R)[0] / kappa_p)

    lo = Rm
    if mismatch(lo) > 0:
        raise ShockError(f"speed {c:g} m/s: a gas shock at the undisturbed radius already produces more entropy "
                         f"than the far state behind carries (admissible range {_range_text(tb)})")
    try:
        hi = Rp
        if mismatch(hi) < 0:
            raise ShockError(f"speed {c:g} m/s: no shock radius between R_- and R_+ (admissible range {_range_text(tb)})")
        Rs = brentq(mismatch, lo, hi, xtol=1e-300, rtol=1e-15, maxiter=400)
    except ShockError:
        raise
    _, ahead, behind = _normal_shock_kappa(tb, c, Rs)
    ts = TravelingShock(c, tb, pp, Rp, up, rhop, Rs, kappa_m, kappa_p, ahead, behind)
    # the profile behind must reach R_+ without turning: (beta1 - a c^2) R'^2 / 2 > 0 on (R_s, R_+)
    # (on a grid; near R_+ it is a double zero computed with cancellation, hence the round-off allowance)
    tol = 1e-12 * (abs(_mass_flux(tb, c)) * c + pp * math.pi * Rp * Rp)
    for t in np.linspace(0.0, 1.0, 201)[1:-1]:
        R = Rs + (Rp - Rs) * t
        rho = _branch_density(tb, c, kappa_p, R, "subsonic")
        if _phi(tb, c, kappa_p, rho, R) < -tol:
            raise ShockError(f"speed {c:g} m/s: the wall behind the shock would turn before reaching R_+ "
                             f"(admissible range {_range_text(tb)})")
    return ts


_RANGE_CACHE = {}


def _edge(exists, good, bad, iterations=40):
    """Bisect between a speed with a solution (``good``) and one without (``bad``); the last good one."""
    for _ in range(iterations):
        mid = 0.5 * (good + bad)
        if exists(mid):
            good = mid
        else:
            bad = mid
    return good


def speed_range_of(tb):
    """(c_min, c_max) of the traveling shock in this tube: c_min the sound speed ahead (weak shocks),
    c_max the largest speed with a solution (below c* = sqrt(beta1/a)), located by bisection to 1e-9."""
    if tb in _RANGE_CACHE:
        return _RANGE_CACHE[tb]
    cs = math.sqrt(tb.gamma * tb.p / tb.rho)
    cstar = math.sqrt(tb.beta1 / tb.a) if tb.a > 0 else math.inf

    def exists(c):
        try:
            _solve_nomsg(tb, c)
            return True
        except ShockError:
            return False

    if cstar <= cs:
        out = (cs, cs)
    else:
        top = min(cstar * (1 - 1e-9), 100 * cs)
        lo = cs * (1 + 1e-6)
        # scan for the first speed where a solution exists, then bisect its upper end
        grid = np.linspace(lo, top, 60)
        have = [exists(c) for c in grid]
        if not any(have):
            out = (cs, cs)
        else:
            k0 = have.index(True)
            lo_ok = grid[k0]
            k1 = k0
            while k1 + 1 < len(grid) and have[k1 + 1]:
                k1 += 1
            high = _edge(exists, grid[k1], grid[k1 + 1]) if k1 + 1 < len(grid) else grid[k1]
            # solutions starting above the sound speed: bisect the lower end too
            low = _edge(exists, lo_ok, grid[k0 - 1]) if k0 > 0 else cs
            out = (low, high)
    _RANGE_CACHE[tb] = out
    return out


def _solve_nomsg(tb, c):
    global _range_text
    saved = _range_text
    _range_text = lambda tb: "…"  # noqa: E731 - avoid recursion while the range itself is searched
    try:
        return _solve(tb, c)
    finally:
        _range_text = saved


def _range_text(tb):
    lo, hi = speed_range_of(tb)
    if hi <= lo:
        return f"empty: no speed admits a traveling shock in this tube (c* = sqrt(beta1/a) = {math.sqrt(tb.beta1 / tb.a) if tb.a else math.inf:.6g} m/s)"
    return f"{lo:.6g} < c < {hi:.6g} m/s"


def make_tube(R0, beta1, beta2, a, p_ext, rho, p, gamma):
    """The tube description used by the traveling-shock functions (SI; ``a = 0`` for a quasistatic wall)."""
    return _Tube(float(R0), float(beta1), float(beta2), float(a), float(p_ext), float(rho), float(p), float(gamma))


def traveling_shock(tube, speed):
    """The traveling shock of speed ``speed`` (m/s) in ``tube`` (:func:`make_tube` or ``varint.scene.derived.tube_of_scene``).

    Returns a :class:`TravelingShock`; raises :class:`ShockError` (one line, naming the admissible range)
    when no such wave exists.
    """
    return _solve(tube, float(speed))


def traveling_shock_of_strength(tube, z):
    """The traveling shock whose far pressure behind is ``p_- (1 + z)``."""
    lo, hi = speed_range_of(tube)
    if not hi > lo:
        raise ShockError(f"strength {z:g}: {_range_text(tube)}")

    def zc(c):
        return traveling_shock(tube, c).strength

    zlo, zhi = zc(lo * (1 + 1e-9) if lo > math.sqrt(tube.gamma * tube.p / tube.rho) else lo * (1 + 1e-7)), zc(hi)
    if not (min(zlo, zhi) < z < max(zlo, zhi)):
        raise ShockError(f"strength {z:g}: outside the admissible range {min(zlo, zhi):.6g} < z < {max(zlo, zhi):.6g} "
                         f"(speeds {_range_text(tube)})")
    c = brentq(lambda c: zc(c) - z, lo * (1 + 1e-7), hi, xtol=1e-12, rtol=1e-14)
    return traveling_shock(tube, c)


def speed_range(tube):
    """(c_min, c_max) in m/s: the speeds for which :func:`traveling_shock` has a solution."""
    return speed_range_of(tube)
