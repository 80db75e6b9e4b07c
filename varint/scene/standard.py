"""Standard scenes for the tests, the scripts and the benchmarks: one place, importable, so that a benchmark and the
test it mirrors build the same scene.

* :func:`gas_scene`: air in the paper's rubber tube (or a rigid one) as a scene dict; :func:`scene_of` validates a
  scene dict (written as TOML by :func:`varint.scene.schema.text.to_toml`).
* :func:`pipe_scene_text`: Païdoussis' dimensionless pipe conveying liquid, for the flowing-pipe tests, sweeps and
  scripts.

The pipe of docs/validation.md ("Modes of a flowing tube", "Open ends on the coupled tube"): L = 1, EI = 1,
M + m = 1 (fluid and pipe mass per length), so that the flow speed U = u / sqrt(M), the mass ratio beta = M/(M+m)
and gravity gamma = (M + m) g L^3/EI of varint.exact.pipe_stability are the scene's own numbers.  A planar (or 3D) [rod],
nearly inextensible (EA = GA = 1e7 EI/L^2) unless ``constraint`` makes it inextensible, carrying an incompressible
liquid in a rigid tube of radius 0.01, with a velocity inlet and a free jet (``open_ends``) or closed at rest.
"""

from __future__ import annotations

import numpy as np

from .schema import parse_scene
from .text import to_toml

__all__ = ["AIR", "RUBBER_WALL", "gas_scene", "scene_of", "pipe_scene_text"]


def pipe_scene_text(ends=("clamped", "free"), beta=0.2, u=1.0, nodes=41, dim=2, gamma=0.0, open_ends=True,
                    constraint="none", parcels=None, h=1e-3, kick=0.0, profile="tip", extra=""):
    """TOML text of the pipe at Païdoussis' (u, beta, gamma).

    ``ends``: the rod's supports at s = 0 and s = L; ``gamma`` > 0 hangs the pipe (gravity along +x, the tube's
    axis); ``parcels`` defaults to one per element (use two per element for runs in time at fast flows,
    docs/theory.md §12); ``kick`` a lateral velocity perturbation [m/s], ``profile`` "tip" (uniform, a step from
    s = 0) or "cosine" (half a cosine wave); ``extra`` text appended to [fluid]'s neighbourhood (e.g. more sections).
    """
    M, m, R = beta, 1.0 - beta, 0.01
    U = float(u / np.sqrt(M)) if open_ends else 0.0
    parcels = nodes - 1 if parcels is None else int(parcels)
    fluid_ends = 'ends = { s0 = "inflow", sL = "outflow" }' if open_ends else ""
    pert = ""
    if kick:
        shape = ('shape = "step"\nfrom = 0.0\nto = 1.0' if profile == "tip"
                 else 'shape = "cosine"\nwavelength = 2.0\nphase = -1.5707963267948966')
        pert = f'[[rod.perturbation]]\nfield = "velocity"\n{shape}\namplitude = {float(kick)!r}\n'
    grav = f"[environment]\ngravity = [{float(gamma)!r}, 0.0, 0.0]\n" if gamma else ""
    return f"""title = "pipe conveying liquid (Paidoussis' dimensionless pipe)"
[tube]
length = 1.0
nodes = {int(nodes)}
radius = {R!r}

[rod]
dimension = {int(dim)}
mass_per_length = {m!r}
rotary_inertia = {m * 1e-6!r}
bending_stiffness = 1.0
torsional_stiffness = 1.0
axial_stiffness = 1.0e7
shear_stiffness = 1.0e7
constraint = "{constraint}"
ends = {{ s0 = "{ends[0]}", sL = "{ends[1]}" }}
{pert}
[fluid]
model = "incompressible"
density = {float(M / (np.pi * R * R))!r}
velocity = {U!r}
pressure = 1.0e5
parcels = {parcels}
{fluid_ends}
{extra}
{grav}
[time]
step = {float(h)!r}
end = {float(h)!r}
"""


#: the paper's rubber tube wall (§4.3) and air at 1 atm, as scene sections
RUBBER_WALL = {"model": "dynamic", "law": "linear", "thickness": 1.0e-3, "density": 1522.0,
               "youngs_modulus": 5.0e6, "poisson_ratio": 0.5}
AIR = {"model": "ideal-gas", "gamma": 1.4, "density": 1.225, "pressure": 101325.0}


def gas_scene(nodes=33, parcels=32, length=1.0, wall=True, ends="closed", h=1e-5, end=1e-3,
              scheme="midpoint", perturbation=None, **extra):
    """Air in a straight tube of radius 5 cm, in the rubber wall (or rigid: ``wall=False``), as a scene dict;
    ``extra``: more sections, replacing the ones given."""
    d = {"title": "test scene",
         "tube": {"length": length, "nodes": nodes, "radius": 0.05},
         "fluid": dict(AIR, parcels=parcels, ends={"s0": ends, "sL": ends}),
         "environment": {"external_pressure": 101325.0},
         "time": {"step": h, "end": end, "scheme": scheme}}
    if wall:
        d["wall"] = dict(RUBBER_WALL)
    if perturbation is not None:
        d["fluid"]["perturbation"] = perturbation
    for k, v in extra.items():
        d[k] = v
    return d


def scene_of(d):
    """The validated :class:`varint.scene.schema.schema.Scene` of a scene dict."""
    return parse_scene(to_toml(d))
