"""Continuum truths for waves in the straight tube: the dispersion relation of the paper's linearised equations
(docs/theory.md §6) and the acoustic modes of a duct of varying area (Webster's horn equation).  Independent of
the lattice."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["dispersion_branches", "webster_frequencies"]


def dispersion_branches(k, c0, rho0, R0, a, beta1, beta2):
    """Angular frequencies (low, high) of small waves exp(i(ks - wt)) in the expandable tube.

    From docs/theory.md §6:  (a/c0^2) w^4 - [(b/c0^2) + 4 pi rho0 + a k^2] w^2 + k^2 b = 0,
    b = beta2 + beta1 k^2, about rest at p = p_ext and R = R0.  ``c0`` is the sound
    speed of the fluid (math.inf for an incompressible liquid).  With a = 0 only
    the low (acoustic/Moens-Korteweg) branch exists and ``high`` is nan.
    """
    k = np.asarray(k, dtype=float)
    b = beta2 + beta1 * k * k
    inv_c2 = 0.0 if math.isinf(c0) else 1.0 / c0 ** 2
    B = b * inv_c2 + 4 * math.pi * rho0 + a * k * k
    C = k * k * b
    A = a * inv_c2
    if A == 0.0:
        return np.sqrt(C / B), np.full_like(k, np.nan)
    disc = np.sqrt(B * B - 4 * A * C)
    # the small root without cancellation
    lo = 2 * C / (B + disc)
    hi = (B + disc) / (2 * A)
    return np.sqrt(lo), np.sqrt(hi)


def webster_frequencies(area, L, c, count, omega_max=None):
    """Closed-closed acoustic frequencies of Webster's horn equation (A p')' + (w/c)^2 A p = 0.

    Shooting with scipy's ``solve_ivp`` from p(0) = 1, p'(0) = 0; roots of p'(L)
    in w bracketed on a fine grid and refined with ``brentq``.  Independent of
    the varint lattice: ``area`` is any callable A(s).
    """
    from scipy.integrate import solve_ivp
    from scipy.optimize import brentq

    def end_slope(w):
        def rhs(s, y):  # y = (p, A p')
            return [y[1] / area(s), -(w / c) ** 2 * area(s) * y[0]]

        sol = solve_ivp(rhs, (0.0, L), [1.0, 0.0], rtol=1e-12, atol=1e-14, method="DOP853")
        return sol.y[1, -1]

    omega_max = omega_max or (count + 1.5) * math.pi * c / L
    grid = np.linspace(1e-6, omega_max, 40 * (count + 2))
    vals = [end_slope(w) for w in grid]
    roots = []
    for (w0, f0), (w1, f1) in zip(zip(grid, vals), zip(grid[1:], vals[1:])):
        if f0 == 0 or f0 * f1 < 0:
            roots.append(brentq(end_slope, w0, w1, xtol=1e-13, rtol=1e-14))
        if len(roots) == count:
            break
    return np.array(roots)
