"""Standard scenes for the tests, the scripts and the benchmarks: one place, importable, so that a benchmark and the
test it mirrors build the same scene.

* :func:`gas_scene`: air in the paper's rubber tube (or a rigid one) as a scene dict; :func:`scene_of` validates a
  scene dict (written as TOML by :func:`varint.scene.text.to_toml`).
* :func:`pipe_scene_text`: Païdoussis' dimensionless pipe conveying liquid, for the flowing-pipe tests, sweeps and
  scripts.

The pipe of docs/validation.md ("Modes of a flowing tube", "Open ends on the coupled tube"): L = 1, EI = 1,
M + m = 1 (fluid and pipe mass per length), so that the flow speed U = u / sqrt(M), the mass ratio beta = M/(M+m)
and gravity gamma = (M + m) g L^3/EI of varint.exact.pipe_stability are the scene's own numbers.  A planar (or 3D) [rod],
nearly inextensible (EA = GA = 1e7 EI/L^2) unless ``constraint`` makes it inextensible, carrying an incompressible
liquid in a rigid tube of radius 0.01, with a velocity inlet and a free jet (``open_ends``) or closed at rest.

The other standard scenes, with the tests and scripts that use them: the rod (:func:`rod_scene`, :func:`tumbling_scene`,
:func:`solid_section`), the spinning shaft and the spun free rod (:func:`shaft_scene`, :func:`blade_scene`), the
coupled tube (:func:`coupled_scene`, :data:`COUPLED_CASES`, :func:`liquid_cantilever_scenes`), shock tubes straight
and on a rod (:func:`shock_tube_scene`, :func:`coupled_sod`), air sloshing and smooth waves in the rubber tube
(:func:`sloshing_scene`, :func:`smooth_wave_scene`) and the periodic flowing pipe (:func:`periodic_pipe_scene`).
A builder returns a scene dict (to change before :func:`scene_of`) or, as the tests had it, the
validated Scene; none builds a model (``varint.build_model(scene)``: the model is a higher layer,
docs/architecture.md).  A few scenes carry their outside truth (:func:`shaft_whirl`, :func:`periodic_pipe_waves`,
:func:`periodic_pipe_critical_speed`: varint.exact with the scene's numbers).
"""

from __future__ import annotations

import math

import numpy as np

from ..exact.beams import flowing_pipe_critical_speed, flowing_pipe_waves, spinning_shaft_whirl
from .schema import parse_scene
from .text import to_toml

__all__ = ["AIR", "RUBBER_WALL", "gas_scene", "scene_of", "pipe_scene_text",
           "ROD_SECTION", "ROD_STIFF_SECTION", "ROD_TUMBLE", "ROD_SPIN", "rod_scene", "tumbling_scene", "solid_section",
           "SHAFT_SECTION", "SHAFT_SPIN_RATE", "shaft_scene", "shaft_whirl", "BLADE_SECTION", "BLADE_SPIN", "blade_scene",
           "COUPLED_SECTION", "GAS", "LIQUID", "BAROTROPIC", "COUPLED_WALL", "coupled_scene", "COUPLED_CASES",
           "liquid_cantilever_scenes",
           "SOD_GAMMA", "SOD", "shock_tube_scene", "SOFT_HOSE_SECTION", "BENT_SPINNING", "SOD_WALL", "coupled_sod",
           "AIR_SOUND_SPEED", "sloshing_scene", "SMOOTH_WAVE", "smooth_wave_scene",
           "FLOWING_PIPE_SECTION", "FLOWING_PIPE_DENSITY", "FLOWING_PIPE_RADIUS", "FLOWING_PIPE_WALL", "FLOWING_PIPE_K",
           "FLOWING_PIPE_STEP", "FLOWING_PIPE_KICK", "periodic_pipe_scene", "periodic_pipe_waves",
           "periodic_pipe_critical_speed"]


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


# ---------------------------------------------------------------------------------------------------------------------
# the rod (tests/test_rod.py and the rod's scripts)

#: a generic 3D rod section in the stiffness form (tests/test_rod.py)
ROD_SECTION = {"mass_per_length": 0.3, "rotary_inertia": 1e-4, "bending_stiffness": 2.0, "torsional_stiffness": 1.5,
               "axial_stiffness": 1e3, "shear_stiffness": 8e2}
#: the same, ten times stiffer in stretch and shear (the tumbling rod)
ROD_STIFF_SECTION = dict(ROD_SECTION, axial_stiffness=1e4, shear_stiffness=8e3)
#: a translating, spinning, uniformly bent initial state
ROD_TUMBLE = {"velocity": [0.1, 0.2, -0.3], "angular_velocity": [1.0, 3.0, -2.0], "curvature": [0.5, 1.0, -0.7]}
#: the tumbling rod's spin about an oblique axis (h |omega| = 0.5 per step at h = 0.01 s)
ROD_SPIN = {"velocity": [0.1, 0.2, -0.3], "angular_velocity": [13.0, 40.0, -27.0]}


def rod_scene(nodes=11, h=1e-3, ends=("free", "free"), initial=None, load=None, gravity=None, dimension=3,
              measure="reference", section=None, length=1.0, end=1.0, perturbation=None):
    """The validated :class:`~varint.scene.schema.Scene` of a rod alone (radius 1 cm, ``section`` in the stiffness
    form, default :data:`ROD_SECTION`); ``initial``, ``load``, ``perturbation``: the [rod] sub-tables."""
    rod = dict(section or ROD_SECTION, dimension=dimension, measure=measure, ends={"s0": ends[0], "sL": ends[1]})
    if perturbation:
        rod["perturbation"] = perturbation
    if initial:
        rod["initial"] = initial
    if load:
        rod["load"] = load
    d = {"title": "rod", "tube": {"length": length, "nodes": nodes, "radius": 0.01}, "rod": rod,
         "time": {"step": h, "end": end}}
    if gravity:
        d["environment"] = {"gravity": gravity}
    return scene_of(d)


def tumbling_scene(h=1e-2, at_rest=False, measure="reference"):
    """The free rod spinning about an oblique axis (10 elements, :data:`ROD_STIFF_SECTION`, :data:`ROD_SPIN`;
    ``at_rest``: the same spin with the centre of mass at rest), as a Scene (tests/test_rod.py,
    scripts/rod_long_run.py)."""
    return rod_scene(nodes=11, h=h, section=ROD_STIFF_SECTION, measure=measure,
                     initial=dict(ROD_SPIN, velocity=[0.0, 0.0, 0.0]) if at_rest else ROD_SPIN)


def solid_section(E=1e6, rad=0.01, rho=1000.0, stretch_factor=None):
    """The stiffness form of a solid circular section of radius ``rad`` (G = E/1.5, shear coefficient 4/3):
    PyElastica's benchmark cantilever (L = 1 m, radius 1 cm, rho = 1000) of scripts/bench_pyelastica.py and
    docs/performance.md.  ``stretch_factor``: axial and shear stiffness set to that many E I instead."""
    G = E / 1.5
    A, I = math.pi * rad ** 2, math.pi * rad ** 4 / 4
    sec = dict(mass_per_length=rho * A, rotary_inertia=rho * I, bending_stiffness=E * I, torsional_stiffness=G * 2 * I,
               axial_stiffness=E * A, shear_stiffness=4.0 / 3.0 * G * A)
    if stretch_factor:
        sec["axial_stiffness"] = sec["shear_stiffness"] = stretch_factor * E * I
    return sec


# -- the spinning shaft and the spun free rod (tests/test_rod_spinning.py, scripts/spinning_shaft_report.py)

#: a thick shaft (radius of gyration 5.8 cm on 1 m) so that the gyroscopic splitting is large; axial and torsional
#: modes placed above the first three bending pairs
SHAFT_SECTION = {"mass_per_length": 0.3, "rotary_inertia": 1e-3, "bending_stiffness": 2.0, "torsional_stiffness": 15.0,
                 "axial_stiffness": 1e5, "shear_stiffness": 8e3}
SHAFT_SPIN_RATE = 60.0  # rad/s about the shaft's axis: 2.3 x its first bending frequency


def shaft_scene(nodes, spin=SHAFT_SPIN_RATE, h=1e-3):
    """The pinned-pinned shaft spinning at ``spin`` about its axis x, as a Scene."""
    return rod_scene(nodes=nodes, section=SHAFT_SECTION, ends=("pinned", "pinned"), h=h,
                     initial={"angular_velocity": [spin, 0.0, 0.0]})


def shaft_whirl(n, spin=SHAFT_SPIN_RATE):
    """Forward and backward whirl of the shaft's bending mode n from the continuum theory (seen from the ground,
    varint.exact.beams.spinning_shaft_whirl)."""
    s = SHAFT_SECTION
    return spinning_shaft_whirl(n * math.pi, s["mass_per_length"], s["rotary_inertia"], 2 * s["rotary_inertia"],
                                s["bending_stiffness"], s["shear_stiffness"], spin)


#: slender, stiff in shear and stretch: the Euler-Bernoulli rotating beam applies (to ~1e-5).  Stiffer still is not
#: better: a dense eigen-solver resolves frequencies to ~1e-7 of the highest one.
BLADE_SECTION = {"mass_per_length": 0.3, "rotary_inertia": 1e-8, "bending_stiffness": 2.0, "torsional_stiffness": 1.5,
                 "axial_stiffness": 1e6, "shear_stiffness": 1e7}
BLADE_SPIN = np.array([0.0, 0.0, 20.0])  # about z, through the centre: the rod turns in the x-y plane


def blade_scene(nodes, h=1e-3):
    """A free rod spun end over end at :data:`BLADE_SPIN` (a rotor blade), as a Scene."""
    return rod_scene(nodes=nodes, section=BLADE_SECTION, h=h, initial={"angular_velocity": list(BLADE_SPIN)})


# ---------------------------------------------------------------------------------------------------------------------
# the coupled tube: rod, fluid and wall (tests/test_coupled_tube.py, tests/test_tube_em.py)

COUPLED_SECTION = {"mass_per_length": 0.5, "rotary_inertia": 1e-4, "bending_stiffness": 5.0, "torsional_stiffness": 4.0,
                   "axial_stiffness": 1e4, "shear_stiffness": 8e3}
GAS = {"model": "ideal-gas", "gamma": 1.4, "density": 1.2, "pressure": 1.0e5}
LIQUID = {"model": "incompressible", "density": 1000.0, "pressure": 1.0e5}
BAROTROPIC = {"model": "barotropic", "density": 1000.0, "pressure": 1.0e5, "bulk_modulus": 2.0e7}
COUPLED_WALL = {"law": "linear", "thickness": 1.0e-3, "density": 1200.0, "youngs_modulus": 5.0e6, "poisson_ratio": 0.45}


def coupled_scene(nodes=7, parcels=8, fluid=GAS, wall=None, ends=("free", "free"), initial=None, gravity=None,
                  dimension=3, h=1e-3, end=1.0, velocity=0.0, radius=0.02, section=None, length=1.0, scheme="midpoint",
                  p_ext=None):
    """The validated Scene of a coupled tube: a rod (``section``, default :data:`COUPLED_SECTION`) carrying
    ``fluid`` (:data:`GAS`, :data:`LIQUID`, :data:`BAROTROPIC`) at ``velocity``; ``wall``: keys over
    :data:`COUPLED_WALL` (None: rigid); ``ends`` ("periodic", "periodic"): the rod and the fluid both periodic."""
    rod = dict(section or COUPLED_SECTION, dimension=dimension, ends={"s0": ends[0], "sL": ends[1]})
    if initial:
        rod["initial"] = initial
    d = {"title": "coupled", "tube": {"length": length, "nodes": nodes, "radius": radius}, "rod": rod,
         "fluid": dict(fluid, parcels=parcels, velocity=velocity), "time": {"step": h, "end": end, "scheme": scheme}}
    if ends == ("periodic", "periodic"):  # a periodic tube: the rod and the fluid both
        d["fluid"]["ends"] = {"s0": "periodic", "sL": "periodic"}
    if wall is not None:
        d["wall"] = dict(COUPLED_WALL, **wall)
    if gravity is not None:
        d["environment"] = {"gravity": gravity}
    if p_ext is not None:
        d.setdefault("environment", {})["external_pressure"] = p_ext
    return scene_of(d)


#: keyword sets of :func:`coupled_scene` that cover the fluids, walls and supports
COUPLED_CASES = {
    "gas-rigid-free-3d": dict(fluid=GAS, initial={"curvature": [0.3, 1.0, 0.5], "angular_velocity": [0.0, 0.0, 3.0]},
                              velocity=2.0, gravity=[0.0, -9.81, 0.0]),
    "gas-dynamic-clamped": dict(fluid=GAS, wall={"model": "dynamic"}, ends=("clamped", "free"),
                                initial={"curvature": [0.0, 1.0, 0.5]}, velocity=1.0),
    "liquid-quasistatic-pinned": dict(fluid=LIQUID, wall={"model": "quasistatic"}, ends=("pinned", "pinned"),
                                      initial={"curvature": [0.0, 0.0, 0.8]}, velocity=0.5),
    "liquid-rigid-free": dict(fluid=LIQUID, initial={"curvature": [0.0, 0.6, 0.0], "angular_velocity": [0.0, 0.0, 2.0]}),
    "barotropic-dynamic-planar": dict(fluid=BAROTROPIC, wall={"model": "dynamic"}, dimension=2, ends=("clamped", "free"),
                                      initial={"curvature": [0.0, 0.0, 1.0]}, velocity=1.0, gravity=[0.0, -9.81, 0.0]),
    "gas-dynamic-periodic": dict(fluid=GAS, wall={"model": "dynamic"}, ends=("periodic", "periodic"), velocity=2.0,
                                 initial={"angular_velocity": [3.0, 0.0, 0.0]}, gravity=[0.0, -9.81, 0.0]),
    "liquid-quasistatic-periodic": dict(fluid=LIQUID, wall={"model": "quasistatic"}, ends=("periodic", "periodic"),
                                        velocity=1.0),
}


def liquid_cantilever_scenes(N, h, R=0.01, L=1.0, rho_f=1000.0, scheme="midpoint"):
    """The water-filled cantilever of docs/theory.md §10.7a (clamped-free, planar, labels on the nodes: N elements,
    N parcels) and the rod alone with the liquid's mass rho_f pi R^2 added to rho A, as two Scenes."""
    sec = dict(COUPLED_SECTION, mass_per_length=0.3, bending_stiffness=2.0, rotary_inertia=1e-5)
    added = rho_f * math.pi * R * R
    coupled = coupled_scene(nodes=N + 1, parcels=N, fluid=dict(LIQUID, density=rho_f), ends=("clamped", "free"),
                            radius=R, section=sec, dimension=2, h=h, length=L, scheme=scheme)
    heavy = scene_of({
        "title": "the rod with the liquid's mass", "tube": {"length": L, "nodes": N + 1, "radius": R},
        "rod": dict(sec, mass_per_length=sec["mass_per_length"] + added, dimension=2,
                    ends={"s0": "clamped", "sL": "free"}), "time": {"step": h, "end": 10.0}})
    return coupled, heavy


# ---------------------------------------------------------------------------------------------------------------------
# shock tubes (tests/test_shock_capturing.py, tests/test_coupled_shock_capturing.py, scripts/coupled_shock_rh.py)

SOD_GAMMA = 1.4
#: Sod's (rho, u, p) left | right of the diaphragm
SOD = ((1.0, 0.0, 1.0), (0.125, 0.0, 0.1))


def shock_tube_scene(M, left=SOD[0], right=SOD[1], h=None, end=0.2, cfl=0.5, shock=None, periodic=False,
                     perturbation=None):
    """A shock tube on [0, 1] (cross-section 1 m^2, closed ends), the diaphragm at 0.5, M equal-length parcels of an
    ideal gas (gamma :data:`SOD_GAMMA`), as a scene dict; ``h`` (default: ``cfl`` parcels per step at the largest
    initial sound speed, rounded to hit ``end``); ``shock``: the [shock_capturing] keys (False: none); ``right``
    None: one state throughout."""
    cmax = max(math.sqrt(SOD_GAMMA * st[2] / st[0]) + abs(st[1]) for st in (left, right or left))
    if h is None:
        n = int(math.ceil(end * M * cmax / cfl))
        h = end / n
    fluid = {"model": "ideal-gas", "gamma": SOD_GAMMA, "density": left[0], "pressure": left[2], "parcels": M}
    if right is not None:
        fluid["initial"] = [{"from": 0.5, "to": 1.0, "density": right[0], "pressure": right[2]}]
    if periodic:
        fluid["ends"] = {"s0": "periodic", "sL": "periodic"}
    if perturbation:
        fluid["perturbation"] = perturbation
    d = {"title": "shock tube", "tube": {"length": 1.0, "nodes": 3, "radius": 1.0 / math.sqrt(math.pi)},
         "fluid": fluid, "time": {"step": h, "end": end}}
    if shock is not False:
        d["shock_capturing"] = shock or {}
    return d


#: a soft hose (bending slow against the gas) that is axially stiff (the gas barely stretches it)
SOFT_HOSE_SECTION = {"mass_per_length": 1.0, "rotary_inertia": 1e-3, "bending_stiffness": 0.05,
                     "torsional_stiffness": 0.04, "axial_stiffness": 1e4, "shear_stiffness": 8e3}
#: bent, spinning about z and translating: the tube's points move at up to ~1 m/s, near the gas's sound speed
BENT_SPINNING = {"curvature": [0.0, 1.0, 0.5], "angular_velocity": [0.0, 0.0, 2.0], "velocity": [0.3, -0.2, 0.1]}
#: a soft linear wall for the 1 m^2 tube (the gas swells it by ~3 %; radial frequency ~6 rad/s)
SOD_WALL = {"law": "linear", "thickness": 1.0e-3, "density": 1000.0, "youngs_modulus": 1.0e4, "poisson_ratio": 0.45}


def coupled_sod(M=50, nodes=11, h=2e-3, end=0.2, initial=None, shock=None, ends=("free", "free"), right=SOD[1],
                wall=None):
    """Sod's tube (1 m, 1 m^2, p_ext = 0) on a rod (:data:`SOFT_HOSE_SECTION`), the diaphragm at s = 0.5, as a
    scene dict; ``wall``: keys over :data:`SOD_WALL`; ``shock``: the [shock_capturing] keys (False: none)."""
    rod = dict(SOFT_HOSE_SECTION, dimension=3, ends={"s0": ends[0], "sL": ends[1]})
    if initial:
        rod["initial"] = initial
    fluid = {"model": "ideal-gas", "gamma": SOD_GAMMA, "density": SOD[0][0], "pressure": SOD[0][2], "parcels": M}
    if right is not None:
        fluid["initial"] = [{"from": 0.5, "to": 1.0, "density": right[0], "pressure": right[2]}]
    if ends[0] == "periodic":
        fluid["ends"] = {"s0": "periodic", "sL": "periodic"}
    d = {"title": "coupled sod", "tube": {"length": 1.0, "nodes": nodes, "radius": 1.0 / math.sqrt(math.pi)},
         "rod": rod, "fluid": fluid, "time": {"step": h, "end": end}, "environment": {"external_pressure": 0.0}}
    if wall is not None:
        d["wall"] = dict(SOD_WALL, **wall)
    if shock is not False:
        d["shock_capturing"] = shock or {}
    return d


# ---------------------------------------------------------------------------------------------------------------------
# air in the rubber tube: sloshing and smooth waves (tests/test_conservation.py, tests/test_convergence.py,
# tests/test_waves.py and their scripts)

#: the speed of sound in :data:`AIR`, sqrt(gamma p / rho)
AIR_SOUND_SPEED = math.sqrt(AIR["gamma"] * AIR["pressure"] / AIR["density"])


def sloshing_scene(h=1e-5, amplitude=0.2, parcels=16, **extra):
    """The closed rubber tube of :func:`gas_scene` with ``parcels`` parcels, sloshing: a pressure perturbation
    ``amplitude`` p0 cos(pi s) (half a wavelength along the tube); ``extra``: :func:`gas_scene`'s keywords."""
    pert = [{"field": "pressure", "shape": "cosine", "amplitude": amplitude * AIR["pressure"], "wavelength": 2.0}]
    return gas_scene(nodes=parcels + 1, parcels=parcels, h=h, perturbation=pert, **extra)


#: a smooth wave in the closed tube: pressure 5 % p0 cos(pi s) and velocity 5 sin(2 pi s) m/s (zero at the closed
#: ends, so the data are compatible with the walls)
SMOOTH_WAVE = [{"field": "pressure", "shape": "cosine", "amplitude": 0.05 * AIR["pressure"], "wavelength": 2.0},
               {"field": "velocity", "shape": "cosine", "amplitude": 5.0, "wavelength": 1.0, "phase": -math.pi / 2}]


def smooth_wave_scene(parcels, h, scheme="midpoint", wall=True):
    """The closed tube of :func:`gas_scene` (rubber wall or rigid) with ``parcels`` parcels carrying
    :data:`SMOOTH_WAVE` (the refinement studies of tests/test_convergence.py)."""
    return gas_scene(nodes=parcels + 1, parcels=parcels, h=h, perturbation=SMOOTH_WAVE, scheme=scheme, wall=wall)


# ---------------------------------------------------------------------------------------------------------------------
# the periodic flowing pipe (tests/test_flowing_pipe.py, scripts/flowing_pipe_linear.py)

#: EI = m = M = 1 (beta = M / (m + M) = 1/2), period L = 1: U_c = 8.47 m/s (Timoshenko, 8.89 Euler-Bernoulli)
FLOWING_PIPE_SECTION = {"mass_per_length": 1.0, "rotary_inertia": 1e-4, "bending_stiffness": 1.0,
                        "torsional_stiffness": 1.0, "axial_stiffness": 400.0, "shear_stiffness": 400.0}
FLOWING_PIPE_DENSITY = 1000.0
FLOWING_PIPE_RADIUS = math.sqrt(1.0 / (FLOWING_PIPE_DENSITY * math.pi))  # M = rho_f pi R^2 = 1 kg/m
FLOWING_PIPE_WALL = {"model": "quasistatic", "law": "linear", "thickness": 1e-3, "density": 7800.0,
                     "youngs_modulus": 2e11, "poisson_ratio": 0.3}
#: the wavenumber of the lateral perturbation (one wavelength along the period)
FLOWING_PIPE_K = 2.0 * math.pi
#: h: the stiff wall's acoustic modes (h omega >= 7) are not resolved; smaller steps and finer lattices meet the
#: flow instability of docs/theory.md §12 (10 elements run at h >= 5e-4, fail at 2.5e-4; 40 elements fail)
FLOWING_PIPE_STEP = 5e-4
#: m/s: linear (the pressure drop of the lengthened loop ~ 1 Pa, against M U^2 / A ~ 1e4 Pa)
FLOWING_PIPE_KICK = 1e-5


def periodic_pipe_scene(U, nodes, parcels, steps, h=FLOWING_PIPE_STEP, amplitude=FLOWING_PIPE_KICK,
                        wall=FLOWING_PIPE_WALL):
    """The periodic pipe (rod and incompressible liquid periodic, a stiff quasistatic wall) carrying a plug flow of
    speed U, kicked by a lateral velocity ``amplitude`` cos(k s) (none at 0), run for ``steps`` steps: a Scene."""
    d = {"title": "periodic flowing pipe", "tube": {"length": 1.0, "nodes": nodes, "radius": FLOWING_PIPE_RADIUS},
         "rod": dict(FLOWING_PIPE_SECTION, dimension=2, ends={"s0": "periodic", "sL": "periodic"},
                     perturbation=[{"field": "velocity", "shape": "cosine", "wavelength": 1.0, "amplitude": amplitude}]),
         "wall": wall,
         "fluid": {"model": "incompressible", "density": FLOWING_PIPE_DENSITY, "pressure": 1e5, "parcels": parcels,
                   "velocity": U, "ends": {"s0": "periodic", "sL": "periodic"}},
         "time": {"step": h, "end": steps * h}}
    if amplitude == 0.0:
        del d["rod"]["perturbation"]
    return scene_of(d)


def periodic_pipe_waves(U):
    """The complex frequencies of the continuum's waves exp(i (k x - omega t)) at the pipe's k and flow speed U
    (varint.exact.beams.flowing_pipe_waves)."""
    s = FLOWING_PIPE_SECTION
    return flowing_pipe_waves(FLOWING_PIPE_K, U, s["bending_stiffness"], s["shear_stiffness"], s["mass_per_length"],
                              s["rotary_inertia"], FLOWING_PIPE_DENSITY * math.pi * FLOWING_PIPE_RADIUS ** 2)


def periodic_pipe_critical_speed():
    """U where the continuum's two bending roots meet (varint.exact.beams.flowing_pipe_critical_speed)."""
    s = FLOWING_PIPE_SECTION
    return flowing_pipe_critical_speed(FLOWING_PIPE_K, s["bending_stiffness"], s["shear_stiffness"],
                                       s["mass_per_length"], s["rotary_inertia"],
                                       FLOWING_PIPE_DENSITY * math.pi * FLOWING_PIPE_RADIUS ** 2)
