"""Equations of state, written as the parcel internal energy psi_k(V) = m_k e(m_k / V, S_k).

Only what the discrete action needs is exposed: psi, psi' = -p and
psi'' = -dp/dV = rho (dp/drho) / V, vectorised over parcels.  Thermodynamic
identities (paper eq. ``thermodynamics``): p = rho^2 de/drho.
"""

from __future__ import annotations

import numpy as np

__all__ = ["IdealGas", "Tait", "make_eos"]


def _power(x, y):
    """x ** y, but inf where Python's float power raises (``1e300 ** 1.4``: OverflowError), as numpy's power gives, so
    that the scene validation and the solvers' finiteness tests see it.  Python's own power is kept otherwise: numpy's
    differs from it in the last bit for some arguments (0.125 ** 1.4), and runs repeat bit for bit."""
    try:
        return x ** y
    except (OverflowError, ZeroDivisionError):
        return np.power(np.float64(x), y)


class IdealGas:
    """Perfect gas p = (gamma - 1) rho e, entropy S = c_v ln(p / rho^gamma), c_v = R / (gamma - 1)."""

    name = "ideal-gas"
    has_entropy = True

    def __init__(self, gamma, gas_constant):
        self.gamma = float(gamma)
        self.cv = float(gas_constant) / (self.gamma - 1.0)

    def entropy(self, rho, p):
        return self.cv * np.log(p / _power(rho, self.gamma))

    def pressure(self, rho, S):
        return np.exp(S / self.cv) * _power(rho, self.gamma)

    def density(self, p, S):
        return _power(p * np.exp(-S / self.cv), 1.0 / self.gamma)

    def sound_speed(self, rho, S):
        return np.sqrt(self.gamma * self.pressure(rho, S) / rho)

    def psi(self, V, m, S):
        """Internal energy m e = p V / (gamma - 1) of each parcel."""
        return self.pressure(m / V, S) * V / (self.gamma - 1.0)

    def dpsi(self, V, m, S):
        p = self.pressure(m / V, S)
        return -p, self.gamma * p / V

    def power_law(self, m, S):
        """(c, K): the parcels' pressure as p(V) = c + K V^-gamma (c = 0, K = exp(S/c_v) m^gamma), the form whose
        mean-value pressure varint.terms.shock_capturing computes."""
        return 0.0, np.exp(np.asarray(S) / self.cv) * np.asarray(m) ** self.gamma


class Tait:
    """Barotropic liquid p = p0 + (B / gamma) ((rho / rho0)^gamma - 1) (gamma = 1: the linear law p0 + B (rho/rho0 - 1)).

    B is the bulk modulus rho dp/drho at rho0, so the sound speed there is sqrt(B / rho0).
    """

    name = "barotropic"
    has_entropy = False

    def __init__(self, rho0, p0, bulk_modulus, gamma):
        self.rho0, self.p0, self.B, self.gamma = float(rho0), float(p0), float(bulk_modulus), float(gamma)

    def pressure(self, rho, S=None):
        x = np.asarray(rho) / self.rho0
        if self.gamma == 1.0:
            return self.p0 + self.B * (x - 1.0)
        return self.p0 + self.B / self.gamma * (x ** self.gamma - 1.0)

    def density(self, p, S=None):
        if self.gamma == 1.0:
            return self.rho0 * (1.0 + (np.asarray(p) - self.p0) / self.B)
        return self.rho0 * (1.0 + self.gamma * (np.asarray(p) - self.p0) / self.B) ** (1.0 / self.gamma)

    def dp_drho(self, rho):
        return self.B / self.rho0 * (np.asarray(rho) / self.rho0) ** (self.gamma - 1.0)

    def sound_speed(self, rho, S=None):
        return np.sqrt(self.dp_drho(rho))

    def psi(self, V, m, S=None):
        rho = m / V
        P = self.p0 - self.B / self.gamma
        if self.gamma == 1.0:
            e = -P / rho + self.B / self.rho0 * np.log(rho / self.rho0)
        else:
            Q = self.B / self.gamma / self.rho0 ** self.gamma
            e = -P / rho + Q * rho ** (self.gamma - 1.0) / (self.gamma - 1.0)
        return m * e

    def dpsi(self, V, m, S=None):
        rho = m / V
        return -self.pressure(rho), rho * self.dp_drho(rho) / V

    def power_law(self, m, S=None):
        """(c, K): the parcels' pressure as p(V) = c + K V^-gamma, c = p0 - B/gamma, K = (B/gamma) (m/rho0)^gamma
        (gamma = 1: the linear law p0 - B + B m / (rho0 V)), the form whose mean-value pressure
        varint.terms.shock_capturing computes."""
        return self.p0 - self.B / self.gamma, self.B / self.gamma * (np.asarray(m) / self.rho0) ** self.gamma


def make_eos(fluid):
    """The equation of state of a scene's ``[fluid]`` section (None if incompressible)."""
    if fluid.model == "ideal-gas":
        return IdealGas(fluid.gamma, fluid.gas_constant)
    if fluid.model == "barotropic":
        return Tait(fluid.density, fluid.pressure, fluid.bulk_modulus, fluid.gamma)
    return None
