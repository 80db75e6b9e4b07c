"""Quantities derived from a scene's keys that more than one layer needs: the wall's coefficients, the tube of a
traveling shock."""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..exact.shocks import ShockError, make_tube

__all__ = ["WallParameters", "wall_parameters", "tube_of_scene"]


@dataclass(frozen=True)
class WallParameters:
    """Resolved wall coefficients (SI); ``a = 0`` for a quasistatic wall."""

    law: str
    a: float
    beta1: float = 0.0
    beta2: float = 0.0
    stiffness: float = 0.0
    tension: float = 0.0


def wall_parameters(wall, R0):
    """The paper's coefficients (eq. ``beta_1_2``) from a scene's ``[wall]``."""
    h, E, nu, rho_s = wall.thickness, wall.youngs_modulus, wall.poisson_ratio, wall.density
    if wall.model == "quasistatic":
        a = 0.0
    else:
        a = wall.a if wall.a is not None else 2 * math.pi * R0 * rho_s * h
    if wall.law == "linear":
        G = None if E is None else E / (2 * (1 + nu))
        beta1 = wall.beta1 if wall.beta1 is not None else 2 * math.pi * wall.shear_coefficient * G * h * R0
        beta2 = wall.beta2 if wall.beta2 is not None else 2 * math.pi / R0 * E * h / (1 - nu * nu)
        return WallParameters("linear", a, beta1=beta1, beta2=beta2)
    stiffness = wall.stiffness if wall.stiffness is not None else E * h / (R0 * (1 - nu * nu))
    return WallParameters("tube-law", a, stiffness=stiffness, tension=wall.tension)


def tube_of_scene(scene):
    """The tube of a scene: [tube] radius, a linear [wall] (dynamic or quasistatic), an ideal gas at rest ahead."""
    src = scene.path or "scene"
    if scene.wall is None or scene.wall.law != "linear":
        raise ShockError(f"{src}: a traveling shock needs a [wall] with law = 'linear' (the wall law of beta_1_2)")
    if scene.fluid is None or scene.fluid.model != "ideal-gas":
        raise ShockError(f"{src}: a traveling shock needs a [fluid] with model = 'ideal-gas'")
    if scene.fluid.velocity != 0.0:
        raise ShockError(f"{src}: fluid.velocity: the gas ahead of a traveling shock must be at rest (0 m/s)")
    w = wall_parameters(scene.wall, scene.tube.radius)
    return make_tube(scene.tube.radius, w.beta1, w.beta2, w.a, scene.environment.external_pressure,
                     scene.fluid.density, scene.fluid.pressure, scene.fluid.gamma)
