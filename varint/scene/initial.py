"""Initial fluid fields of a scene: base state, piecewise regions, then perturbations.

With ``[initial.traveling_shock]`` the fields are instead the traveling shock's profile
(varint.exact.shocks, docs/theory.md §11) with the shock at ``position``.

Perturbations of pressure or density are isentropic: the other variable follows
at the parcel's entropy (ideal gas) or along the barotrope (Tait).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["shape_profile", "initial_fields", "InitialFields"]


def shape_profile(p, x):
    """A perturbation profile (scene ``[[...perturbation]]``) evaluated at x."""
    x = np.asarray(x, dtype=np.float64)
    if p.shape == "traveling_shock":  # internal: set by [initial.traveling_shock] (varint.scene.schema)
        return p.wave.profile(x - p.position)[0] - p.wave.tube.R0
    if p.shape == "cosine":
        return p.amplitude * np.cos(2 * math.pi * x / p.wavelength + p.phase)
    if p.shape == "gaussian":
        return p.amplitude * np.exp(-0.5 * ((x - p.center) / p.width) ** 2)
    return np.where((x >= p["from"]) & (x <= p["to"]), p.amplitude, 0.0)


@dataclass
class InitialFields:
    """Callables giving density, entropy (parcel centres) and velocity (labels)."""

    fluid: object
    eos: object

    def _thermo(self, x):
        f, eos = self.fluid, self.eos
        rho = np.full(x.shape, f.density, dtype=np.float64)
        if eos is None:  # incompressible: density is constant, there is no entropy
            return rho, np.zeros_like(rho)
        ts = f.get("traveling_shock")  # set by the validator with [initial.traveling_shock] only
        if ts is not None:  # [initial.traveling_shock]: the wave's profile at t = 0
            _, rho, _, p = ts.wave.profile(x - ts.position)
            return rho, eos.entropy(rho, p)
        p = np.full(x.shape, f.pressure, dtype=np.float64)
        S_base = eos.entropy(f.density, f.pressure) if eos.has_entropy else 0.0
        S = np.full(x.shape, S_base)
        for r in f.initial:
            mask = (x >= r["from"]) & (x <= r["to"])
            if r.density is not None and r.pressure is not None and eos.has_entropy:
                rho[mask], p[mask] = r.density, r.pressure
                S[mask] = eos.entropy(r.density, r.pressure)
            elif r.pressure is not None:
                p[mask] = r.pressure
                rho[mask] = eos.density(p[mask], S[mask])
            elif r.density is not None:
                rho[mask] = r.density
                p[mask] = eos.pressure(rho[mask], S[mask])
        for pert in f.perturbation:
            d = shape_profile(pert, x)
            if pert.field == "pressure":
                p = p + d
                if np.any(p <= 0) and eos.has_entropy:
                    raise ValueError("fluid.perturbation: makes the pressure non-positive somewhere")
                rho = eos.density(p, S)
            elif pert.field == "density":
                rho = rho + d
                if np.any(rho <= 0):
                    raise ValueError("fluid.perturbation: makes the density non-positive somewhere")
                p = eos.pressure(rho, S)
        if np.any(~np.isfinite(rho)) or np.any(rho <= 0):
            raise ValueError("fluid.initial: the initial state has a non-positive or undefined density somewhere")
        return rho, S

    def density(self, x):
        return self._thermo(np.asarray(x, dtype=np.float64))[0]

    def entropy(self, x):
        return self._thermo(np.asarray(x, dtype=np.float64))[1]

    def velocity(self, x):
        x = np.asarray(x, dtype=np.float64)
        ts = self.fluid.get("traveling_shock")  # set by the validator with [initial.traveling_shock] only
        if ts is not None:
            return ts.wave.profile(x - ts.position)[2]
        u = np.full(x.shape, self.fluid.velocity, dtype=np.float64)
        for r in self.fluid.initial:
            if r.velocity is not None:
                u[(x >= r["from"]) & (x <= r["to"])] = r.velocity
        for pert in self.fluid.perturbation:
            if pert.field == "velocity":
                u = u + shape_profile(pert, x)
        return u


def initial_fields(fluid, eos):
    return InitialFields(fluid, eos)
