"""Scene files: TOML text -> a validated, fully resolved :class:`Scene`.

The accepted keys are declared once, in :data:`SCHEMA`; the validator, the
``varint check`` report and ``docs/scenes.md`` (``scripts/write_scene_docs.py``)
all read that declaration, so they cannot drift apart.  Every problem found is
reported as one line ``key.path: what is wrong``; unknown keys are errors with
the nearest valid key suggested.  A scene is data: nothing in it is evaluated.
"""

from __future__ import annotations

import difflib
import math
import tomllib
import unicodedata
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType

from ..errors import SceneError

__all__ = ["Key", "SCHEMA", "Scene", "load_scene", "parse_scene", "step_count", "MAX_STEPS"]

REQUIRED = object()

#: the most steps a run may take (time.end / time.step): a billion steps of the cheapest scene take days
MAX_STEPS = 10**9
_MAX_STEPS_TEXT = f"10^{round(math.log10(MAX_STEPS))}"


@dataclass(frozen=True)
class Key:
    """Declaration of one scene key.

    ``kind`` is one of ``float``, ``int``, ``str``, ``vec3``, ``pairs``
    (list of [x, y] numbers) or ``strlist``.  ``low``/``high`` bound numbers,
    ``low_open`` makes the lower bound strict.  ``choices`` restricts strings.
    """

    name: str
    kind: str
    default: object = REQUIRED
    unit: str = ""
    doc: str = ""
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    choices: tuple = ()


def _num(x):
    """A bound or value as written in messages and docs: whole numbers without an exponent."""
    return f"{int(x)}" if float(x).is_integer() and abs(x) < 1e15 else f"{x:g}"


def _pos(name, unit, doc, default=REQUIRED):
    return Key(name, "float", default, unit, doc, low=0.0, low_open=True)


SHAPE_KEYS = (
    Key("field", "str", REQUIRED, "", "quantity perturbed", choices=("pressure", "density", "velocity", "R")),
    Key("shape", "str", REQUIRED, "", "profile of the perturbation", choices=("cosine", "gaussian", "step")),
    Key("amplitude", "float", REQUIRED, "field unit", "added to the field (pressure: Pa, density: kg/m^3, velocity: m/s, R: m)"),
    Key("wavelength", "float", None, "m", "cosine: amplitude*cos(2*pi*s/wavelength + phase)", low=0.0, low_open=True),
    Key("phase", "float", 0.0, "rad", "cosine: phase"),
    Key("center", "float", None, "m", "gaussian: amplitude*exp(-(s-center)^2/(2*width^2)); on the tube, 0 <= center <= L"),
    Key("width", "float", None, "m", "gaussian: standard deviation", low=0.0, low_open=True),
    Key("from", "float", None, "m", "step: start of the interval where the amplitude is added"),
    Key("to", "float", None, "m", "step: end of that interval (which must meet the tube [0, L])"),
)

#: Every accepted key, by section.  Sub-tables are ``section.sub``; arrays of
#: tables are marked by a trailing ``[]``.
SCHEMA = MappingProxyType({
    "": (Key("title", "str", REQUIRED, "", "one-line description of the scene (no string of a scene may hold control "
             "characters or line breaks)"),),
    "tube": (
        _pos("length", "m", "tube length L"),
        # the upper bound keeps the lattice's unknowns and their Jacobian within a few GB (as fluid.parcels')
        Key("nodes", "int", REQUIRED, "", "number of lattice nodes N+1 along the tube (N elements)", low=3, high=2_000_001),
        _pos("radius", "m", "reference (undeformed) inner radius R0"),
        Key("area_table", "pairs", None, "[m, m^2]", "rigid wall only: cross-section A(s) as [[s, A], ...] points, linearly interpolated; replaces the uniform pi*R0^2"),
    ),
    "wall": (
        Key("model", "str", "dynamic", "", "dynamic: wall inertia a; quasistatic: a = 0, R follows the fluid", choices=("dynamic", "quasistatic")),
        Key("law", "str", "linear", "", "wall energy F(R,R'): linear = 1/2 beta1 R'^2 + 1/2 beta2 (R-R0)^2; tube-law = Pedley-Luo form T/2 (dA/ds)^2 + f(A), f' = beta (sqrt(A)-sqrt(A0))/sqrt(A0)", choices=("linear", "tube-law")),
        Key("a", "float", None, "kg/m", "wall inertia per unit length (default 2 pi R0 rho_s h)", low=0.0, low_open=True),
        Key("beta1", "float", None, "N", "linear law: coefficient of R'^2 (default 2 pi K G h R0)", low=0.0),
        Key("beta2", "float", None, "N/m^2", "linear law: coefficient of (R-R0)^2 (default 2 pi E h / (R0 (1-nu^2)))", low=0.0, low_open=True),
        Key("stiffness", "float", None, "Pa", "tube law: beta in Phi(A) (default E h / (R0 (1-nu^2)))", low=0.0, low_open=True),
        Key("tension", "float", 0.0, "N/m^2 * m^2", "tube law: longitudinal coefficient T of (dA/ds)^2", low=0.0),
        Key("thickness", "float", None, "m", "wall thickness h", low=0.0, low_open=True),
        Key("density", "float", None, "kg/m^3", "wall material density rho_s", low=0.0, low_open=True),
        Key("youngs_modulus", "float", None, "Pa", "Young's modulus E", low=0.0, low_open=True),
        Key("poisson_ratio", "float", 0.5, "", "Poisson ratio nu", low=0.0, high=0.5),
        Key("shear_coefficient", "float", 5.0 / 6.0, "", "Timoshenko coefficient K in beta1 = 2 pi K G h R0", low=0.0, low_open=True),
    ),
    "wall.perturbation[]": SHAPE_KEYS,
    "fluid": (
        Key("model", "str", REQUIRED, "", "equation of state", choices=("ideal-gas", "barotropic", "incompressible")),
        Key("gamma", "float", None, "", "ideal gas: ratio of specific heats (default 1.4); barotropic: Tait exponent (default 7.15)", low=1.0),
        Key("density", "float", REQUIRED, "kg/m^3", "initial (reference) density", low=0.0, low_open=True),
        Key("pressure", "float", None, "Pa", "initial pressure (required for ideal-gas and barotropic; incompressible: initial guess of the multiplier, default the external pressure)"),
        Key("velocity", "float", 0.0, "m/s", "initial velocity along the tube (0 for a liquid in a closed rigid tube on a "
            "[rod]: the column cannot flow)"),
        # the upper bound keeps the (M+1)-sized Jacobian and its factorisation within a few GB
        Key("parcels", "int", REQUIRED, "", "number of fluid parcels M (labels k = 0..M); flowing liquid on a [rod]: at "
            "least 2 per element (docs/theory.md §12, labels passing the nodes)", low=2, high=2_000_000),
        Key("gas_constant", "float", 287.05, "J/(kg K)", "ideal gas: specific gas constant (sets the entropy unit c_v = R/(gamma-1))", low=0.0, low_open=True),
        Key("bulk_modulus", "float", None, "Pa", "barotropic: bulk modulus K = rho dp/drho at the reference density", low=0.0, low_open=True),
    ),
    "fluid.ends": (
        Key("s0", "str", "closed", "", "end s = 0", choices=("closed", "periodic", "inflow")),
        Key("sL", "str", "closed", "", "end s = L", choices=("closed", "periodic", "outflow")),
        Key("inflow", "str", "velocity", "", "open ends: what the inlet at s = 0 prescribes (velocity: a piston pushing parcels "
            "in at inflow_velocity; pressure: inflow_pressure acting on the last parcel entering), docs/theory.md §13",
            choices=("velocity", "pressure")),
        Key("inflow_velocity", "float", None, "m/s", "open ends: velocity of the entering fluid (default fluid.velocity)", low=0.0, low_open=True),
        Key("inflow_density", "float", None, "kg/m^3", "open ends: density of the entering fluid (default fluid.density); with inflow_pressure "
            "it sets the entering parcels' mass (inflow_density x parcel volume) and entropy; at a velocity inlet they enter at the "
            "pressure of the parcel they join (docs/theory.md §13.2)", low=0.0, low_open=True),
        Key("inflow_pressure", "float", None, "Pa", "open ends: pressure of the entering fluid (default fluid.pressure): a pressure inlet's "
            "pressure; with inflow_density, the entering gas's entropy"),
        Key("outflow_pressure", "float", None, "Pa", "open ends: pressure at the outlet s = L (default environment.external_pressure: a free jet)"),
        Key("outflow", "str", "pressure", "", "open ends: the outlet (pressure: outflow_pressure on the last parcel; non-reflecting: "
            "outflow_pressure + rho c (u - fluid.velocity), an outgoing wave leaves without reflection; windkessel: the three-element "
            "R-C-R load windkessel_R1, _C, _R2 draining to outflow_pressure), docs/theory.md §13.9",
            choices=("pressure", "non-reflecting", "windkessel")),
        Key("windkessel_R1", "float", None, "Pa s/m^3", "outflow = 'windkessel': proximal resistance R1 (p_outlet = p_C + R1 Q)", low=0.0),
        Key("windkessel_C", "float", None, "m^3/Pa", "outflow = 'windkessel': compliance C (C dp_C/dt = Q - (p_C - outflow_pressure)/R2)",
            low=0.0, low_open=True),
        Key("windkessel_R2", "float", None, "Pa s/m^3", "outflow = 'windkessel': distal resistance R2", low=0.0, low_open=True),
    ),
    "fluid.initial[]": (
        Key("from", "float", REQUIRED, "m", "start of the region"),
        Key("to", "float", REQUIRED, "m", "end of the region"),
        Key("density", "float", None, "kg/m^3", "density in the region", low=0.0, low_open=True),
        Key("pressure", "float", None, "Pa", "pressure in the region", low=0.0, low_open=True),
        Key("velocity", "float", None, "m/s", "velocity in the region"),
    ),
    "fluid.perturbation[]": SHAPE_KEYS,
    "initial.traveling_shock": (
        Key("speed", "float", REQUIRED, "m/s", "speed c of a traveling shock moving towards +s into the gas of [fluid] (at rest); "
            "the fluid and wall start on its profile (docs/theory.md §11; varint shock SCENE --speed C shows it)", low=0.0, low_open=True),
        Key("position", "float", REQUIRED, "m", "position of the shock along the tube at t = 0"),
    ),
    "rod": (
        Key("dimension", "int", 3, "", "3: full SE(3) motion; 2: planar motion in the x-y plane (3 unknowns per node)", low=2, high=3),
        Key("measure", "str", "reference", "", "reference: densities per reference length (mass per length fixed); paper: every density times |Gamma| as in Lagrangian_fluid_tube (drifts in energy for stiff stretching at large omega h, docs/validation.md)", choices=("paper", "reference")),
        Key("constraint", "str", "none", "", "none: stretch and shear with the axial and shear stiffness; inextensible_unshearable: Gamma = E_1 held by multipliers (the paper's inext_unshear limit; no stiff axial and shear modes, docs/theory.md §9a)", choices=("none", "inextensible_unshearable")),
        Key("youngs_modulus", "float", None, "Pa", "material form: Young's modulus E", low=0.0, low_open=True),
        Key("shear_modulus", "float", None, "Pa", "material form: shear modulus G (default E/3)", low=0.0, low_open=True),
        Key("density", "float", None, "kg/m^3", "material form: density", low=0.0, low_open=True),
        Key("thickness", "float", None, "m", "material form: wall thickness of the annulus whose inner radius is tube.radius", low=0.0, low_open=True),
        Key("shear_coefficient", "float", 4.0 / 3.0, "", "material form: k in the shear stiffness k G A (default 4/3, PyElastica's alpha_c, for comparable runs)", low=0.0, low_open=True),
        Key("mass_per_length", "float", None, "kg/m", "stiffness form: rho A", low=0.0, low_open=True),
        Key("rotary_inertia", "float", None, "kg m", "stiffness form: rho I about a bending axis, per length (polar: twice)", low=0.0, low_open=True),
        Key("bending_stiffness", "float", None, "N m^2", "stiffness form: E I", low=0.0, low_open=True),
        Key("torsional_stiffness", "float", None, "N m^2", "stiffness form: G J", low=0.0, low_open=True),
        Key("axial_stiffness", "float", None, "N", "stiffness form: E A", low=0.0, low_open=True),
        Key("shear_stiffness", "float", None, "N", "stiffness form: k G A", low=0.0, low_open=True),
    ),
    "rod.ends": (
        Key("s0", "str", "clamped", "", "support at s = 0 (periodic: at both ends, a straight periodic tube of period L along x)", choices=("clamped", "pinned", "free", "periodic")),
        Key("sL", "str", "free", "", "support at s = L", choices=("clamped", "pinned", "free", "periodic")),
    ),
    "rod.initial": (
        Key("velocity", "vec3", (0.0, 0.0, 0.0), "m/s", "rigid translation velocity"),
        Key("angular_velocity", "vec3", (0.0, 0.0, 0.0), "rad/s", "rigid rotation about the centre of mass (spatial)"),
        Key("curvature", "vec3", (0.0, 0.0, 0.0), "1/m", "uniform body curvature of the initial shape (the stress-free reference stays straight along +x)"),
        Key("shape", "str", "given", "", "\"given\": start from that shape; \"steady_rotation\": from the shape at rest in the frame "
            "spinning with angular_velocity (stretched by the centrifugal loads, as varint static finds it)",
            choices=("given", "steady_rotation")),
    ),
    "rod.perturbation[]": (
        Key("field", "str", REQUIRED, "", "quantity perturbed: the nodes' initial velocity, added to rod.initial's rigid motion",
            choices=("velocity",)),
        Key("direction", "vec3", (0.0, 1.0, 0.0), "", "direction of the added velocity (normalised; a planar rod: in the x-y plane)"),
    ) + tuple(k for k in SHAPE_KEYS if k.name not in ("field", "amplitude")) + (
        Key("amplitude", "float", REQUIRED, "m/s", "added velocity at the profile's peak (s: the reference arc length)"),
    ),
    "rod.load": (
        Key("force", "vec3", (0.0, 0.0, 0.0), "N", "dead force at s = L"),
        Key("torque", "vec3", (0.0, 0.0, 0.0), "N m", "dead (spatial) torque at s = L: by Lagrange-d'Alembert (midpoint), as tip director forces with its work summed "
            "(energy-momentum)"),
    ),
    "environment": (
        Key("external_pressure", "float", None, "Pa", "uniform pressure outside the wall (default: the fluid's initial pressure, so the reference tube is in equilibrium; 0 without fluid)"),
        Key("gravity", "vec3", (0.0, 0.0, 0.0), "m/s^2", "gravitational acceleration; the straight tube (no [rod]) lies "
            "along +x and only g_x acts, on its fluid: other components, or gravity without [fluid], are refused"),
    ),
    "time": (
        _pos("step", "s", "time step h"),
        _pos("end", "s", "final time: the run takes ceil(end/step) steps, so it ends at end when end is a multiple of step "
             "and otherwise at the first multiple of step after end (varint check and varint run say so in one line); "
             "at most 10^9 steps"),
        Key("scheme", "str", "midpoint", "", "the step: 'midpoint' (variational, symplectic; docs/theory.md §4), "
            "'trapezoidal' (its potential by the trapezoidal rule, a tube without algebraic unknowns), 'energy-momentum' "
            "(energy and momenta conserved to the solver's tolerance at any step; a dead tip torque changes them by its "
            "work and impulse; the rod §12a, the coupled tube with closed ends §12b, the straight tube with a compressible "
            "fluid §12d: docs/capabilities.md lists what each covers), or 'auto' (the energy-momentum scheme where it "
            "covers the scene, else the midpoint: long coupled runs the midpoint loses, docs/validation.md 'Long runs')",
            choices=("midpoint", "trapezoidal", "energy-momentum", "auto")),
        Key("newton_tol", "float", 1e-12, "", "Newton stops when the scaled update is below this", low=0.0, low_open=True),
        Key("max_iterations", "int", 25, "", "Newton iterations before the step is declared failed", low=1),
        Key("adaptive", "bool", True, "", "step control: a step that fails at time.step (Newton, a frame turning by more "
            "than 90 degrees, a folded lattice) is taken as two half steps (down to 1/8), then the run returns to "
            "time.step; the monitors count them (halved_steps); false: stop at the first failure (docs/theory.md §4b)"),
    ),
    "shock_capturing": (
        Key("quadratic", "float", 1.0, "", "c_Q of the von Neumann-Richtmyer viscous pressure Q = rho (c_Q^2 du^2 + c_L c abs(du)), "
            "acting in compression only (du < 0: the jump of the step's label velocity across a parcel); c_Q sets the "
            "shock's width in parcels (docs/theory.md §11a). Needs an ideal gas and the midpoint scheme: in a straight tube, "
            "rigid (uniform or tube.area_table) or with a dynamic wall (no quasistatic wall), also on a [rod]", low=0.0),
        Key("linear", "float", 0.5, "", "c_L of the linear (Landshoff) part of Q: damps the ringing behind the shock "
            "(and, at first order, smooth compressions: see limiter)", low=0.0),
        Key("limiter", "str", "none", "", "christensen: Christensen's limiter on Q, no viscosity in smooth compressions "
            "(for long runs of smooth waves; the strong shock tubes converge more slowly with it)",
            choices=("none", "christensen")),
    ),
    "output": (
        Key("file", "str", None, "", "HDF5 run file (default: the scene name with .h5)"),
        Key("every", "int", 1, "", "write every this many steps", low=1),
        Key("fields", "strlist", None, "", "field groups to write (default all of the model's): fluid, wall, rod (the groups of the scene's effects)"),
    ),
})

NOT_YET = {}


class Section(dict):
    """A resolved scene section: a dict whose keys also read as attributes.

    The validator fills every key :data:`SCHEMA` declares for the section (its value, its default or None), so an
    attribute that is not a key is a misspelling: reading it raises AttributeError naming the section and the key
    (``fluid.densty: no such key in this section``) instead of reading None.  A key the code adds only in some
    scenes (``fluid.traveling_shock``) is read with ``section.get(key)`` or ``key in section``.
    """

    #: where the section sits in the scene ("fluid", "fluid.ends", "rod.perturbation[0]"), for the message
    _path = "(section)"

    def __getattr__(self, name):
        if name.startswith("_"):  # protocols (copy, pickle, numpy) look their hooks up here: not keys
            raise AttributeError(name)
        try:
            return self[name]
        except KeyError:
            raise AttributeError(f"{self._path}.{name}: no such key in this section") from None

    @classmethod
    def at(cls, path, *args, **kwargs):
        """A Section at ``path`` in the scene, with the items of ``dict(*args, **kwargs)``."""
        out = cls(*args, **kwargs)
        out._path = path
        return out

    def __repr__(self):  # pragma: no cover - debugging aid
        return f"Section({dict.__repr__(self)})"


@dataclass
class Scene:
    """A validated scene.  Absent optional sections are ``None``."""

    title: str
    tube: Section
    time: Section
    output: Section
    environment: Section
    wall: Section | None = None
    fluid: Section | None = None
    rod: Section | None = None
    initial: Section | None = None
    shock_capturing: Section | None = None
    text: str = ""
    path: str | None = None
    derived: dict = field(default_factory=dict)

    @property
    def effects(self):
        """Names of the effects this scene switches on, in assembly order."""
        eff = []
        if self.rod is not None:
            eff.append("rod")
        if self.wall is not None:
            eff.append("wall")
        if self.fluid is not None:
            eff.append("fluid")
        if self.external_pressure_acts:
            eff.append("external_pressure")
        if self.gravity_acts:
            eff.append("gravity")
        if self.shock_capturing is not None:
            eff.append("shock_capturing")
        return eff

    @property
    def external_pressure_acts(self):
        # p_ext only does work on a moving wall, or on a tube whose rod stretches (docs/theory.md §10.4.2)
        return self.wall is not None or (self.rod is not None and self.fluid is not None)

    @property
    def steps(self):
        """Number of steps of a run of this scene (``step_count``)."""
        return step_count(self.time.end, self.time.step)

    @property
    def end_note(self):
        """One line saying where a run ends when ``time.end`` is not a multiple of ``time.step``, else None."""
        n, h, end = self.steps, self.time.step, self.time.end
        if abs(n * h - end) <= 1e-9 * end:
            return None
        return (f"time.end = {end:g} s is not a multiple of time.step = {h:g} s: the run takes {n} steps and ends at "
                f"t = {n * h:.10g} s")

    @property
    def gravity_acts(self):
        # A fixed centreline lies along +x: only g_x acts, and only on fluid; a rod feels all of g.
        g = self.environment.gravity
        if self.rod is not None:
            return any(x != 0.0 for x in g)
        return self.fluid is not None and g[0] != 0.0


def step_count(end, step):
    """The number of steps of a run to ``end`` at ``step``: ceil(end / step), where an end within 1e-9 (relative) of a
    multiple of the step counts as that multiple (2e-4 / 1e-5 is 20.000000000000004 in floating point: 20 steps).
    A run whose end is not a multiple of its step thus ends at the first multiple after it (docs/scenes.md)."""
    x = end / step
    if not math.isfinite(x) or x > 2 * MAX_STEPS:
        raise SceneError(f"time.end: time.end / time.step = {x:.3g} steps, more than the {_MAX_STEPS_TEXT} a run may take")
    n = round(x)
    return int(n) if abs(x - n) <= 1e-9 * max(1.0, x) else int(math.ceil(x))


class _ResolvedKeys:
    """The resolved value of a dotted key of a validated scene (``fluid.initial[0].density``), None when absent."""

    def __init__(self, scene):
        self.scene = scene

    def __call__(self, key):
        obj = self.scene
        for part in key.split("."):
            name, _, index = part.partition("[")
            obj = obj.get(name) if isinstance(obj, dict) else getattr(obj, name, None)
            if obj is None:
                return None
            if index:
                obj = obj[int(index.rstrip("]"))]
        return obj


def load_scene(path):
    """Read and validate a scene file.  Raises :class:`SceneError`."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")  # TOML is UTF-8 whatever the locale
    except FileNotFoundError:
        raise SceneError("no such file", source=str(path)) from None
    except UnicodeDecodeError:
        raise SceneError("not a text (UTF-8) TOML file", source=str(path)) from None
    except (IsADirectoryError, PermissionError) as exc:
        raise SceneError(f"cannot read: {exc.__class__.__name__}", source=str(path)) from None
    return parse_scene(text, source=str(path))


def parse_scene(text, source=None):
    """Validate scene text; returns a :class:`Scene` or raises :class:`SceneError`."""
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"TOML syntax error: {exc}", source=source) from None
    except RecursionError:  # the reader recurses into nested tables and arrays
        raise SceneError("TOML nesting too deep (tables or arrays nested hundreds of levels; a scene nests three at "
                         "most)", source=source) from None
    except ValueError as exc:  # Python's limit on integer literals (sys.get_int_max_str_digits)
        raise SceneError(f"TOML value not readable: {str(exc).split(':')[0]}", source=source) from None
    if not raw:
        raise SceneError("holds no keys: a scene needs a title, [tube], [time] and a [rod], [fluid] or [wall]",
                         source=source)
    v = _Validator()
    scene = v.scene(raw)
    if v.problems:
        raise SceneError(v.problems, source=source)
    scene.text = text
    scene.path = source
    return scene


# ---------------------------------------------------------------------------
# validation


def _fmt(x, limit=60):
    """A value as quoted in a message: strings with their escapes (a message stays one printable line), anything
    longer than ``limit`` characters cut short."""
    try:
        text = repr(x) if isinstance(x, str) else str(x)
    except (RecursionError, ValueError):  # a structure nested too deep to print, an int too long to convert
        text = f"<{type(x).__name__}>"
    return text if len(text) <= limit else text[:limit - 4] + " ..."


#: Unicode categories no string of a scene may hold: control characters (U+0000-U+001F, U+007F-U+009F: a NUL ends a
#: C string in HDF5, an escape sequence rewrites the terminal) and line or paragraph separators (they would split
#: a one-line message)
_FORBIDDEN_CATEGORIES = ("Cc", "Zl", "Zp")


def _control_character(text):
    """The first character of ``text`` that no scene string may hold, as ``U+XXXX at position i``, or None."""
    for i, c in enumerate(text):
        if unicodedata.category(c) in _FORBIDDEN_CATEGORIES:
            return f"U+{ord(c):04X} at position {i}"
    return None


def _key_text(name):
    """A key's name as written in a message: quoted with its escapes when it holds what a line cannot show."""
    return name if name.isprintable() and name.strip() == name and name else repr(name)


class _Validator:
    def __init__(self):
        self.problems = []

    def bad(self, path, msg):
        self.problems.append(f"{path}: {msg}")

    # -- generic key checking ------------------------------------------------

    def section(self, raw, schema_name, path):
        """Check one table against its declared keys; returns a Section."""
        keys = {k.name: k for k in SCHEMA[schema_name]}
        subtables = {n.split(".", 1)[1].rstrip("[]") for n in SCHEMA if n.startswith(schema_name + ".") and schema_name}
        out = Section.at(path or "(top level)")
        if not isinstance(raw, dict):
            self.bad(path or "(top level)", f"must be a table, got {type(raw).__name__}")
            raw = {}
        for name in raw:
            if name not in keys and name not in subtables:
                self.unknown(path, name, list(keys) + sorted(subtables))
        for k in keys.values():
            kp = f"{path}.{k.name}" if path else k.name
            if k.name in raw:
                out[k.name] = self.value(raw[k.name], k, kp)
            elif k.default is REQUIRED:
                self.bad(kp, "missing (required)")
                out[k.name] = None
            else:
                out[k.name] = k.default
        return out

    def unknown(self, path, name, valid):
        kp = f"{path}.{_key_text(name)}" if path else _key_text(name)
        near = difflib.get_close_matches(name, valid, n=1, cutoff=0.6)
        hint = f" (did you mean '{near[0]}'?)" if near else f" (valid: {', '.join(valid)})"
        self.bad(kp, "unknown key" + hint)

    def value(self, x, k, kp):
        if k.kind in ("float", "int"):
            if isinstance(x, bool) or not isinstance(x, (int, float)):
                self.bad(kp, f"must be a number, got {type(x).__name__} {_fmt(x)}")
                return None
            if k.kind == "int" and not isinstance(x, int):
                if not math.isfinite(x):
                    self.bad(kp, f"must be finite, got {x}")
                    return None
                if float(x).is_integer():
                    x = int(x)
                else:
                    self.bad(kp, f"must be a whole number, got {x}")
                    return None
            try:
                float(x)
            except OverflowError:  # an integer of hundreds of digits
                self.bad(kp, f"is too large ({len(str(abs(x)))} digits)")
                return None
            if not math.isfinite(x):
                self.bad(kp, f"must be finite, got {x}")
                return None
            if k.low is not None and (x <= k.low if k.low_open else x < k.low):
                self.bad(kp, f"must be {'>' if k.low_open else '>='} {k.low:g}, got {x:g}")
                return None
            if k.high is not None and x > k.high:
                self.bad(kp, f"must be <= {_num(k.high)}, got {_num(x)}")
                return None
            return float(x) if k.kind == "float" else int(x)
        if k.kind == "str":
            if not isinstance(x, str):
                self.bad(kp, f"must be a string, got {type(x).__name__} {_fmt(x)}")
                return None
            bad_char = _control_character(x)
            if bad_char:
                self.bad(kp, f"must not contain control characters or line breaks, got {_fmt(x)} ({bad_char})")
                return None
            if k.choices and x not in k.choices:
                near = difflib.get_close_matches(x, k.choices, n=1)
                hint = f" (did you mean '{near[0]}'?)" if near else ""
                self.bad(kp, f"unknown value {_fmt(x)}; choose one of {', '.join(k.choices)}{hint}")
                return None
            return x
        if k.kind == "bool":
            if not isinstance(x, bool):
                self.bad(kp, f"must be true or false, got {_fmt(x)}")
                return None
            return x
        if k.kind == "vec3":
            ok = isinstance(x, list) and len(x) == 3 and all(isinstance(c, (int, float)) and not isinstance(c, bool) and math.isfinite(c) for c in x)
            if not ok:
                self.bad(kp, f"must be a list of 3 finite numbers, got {_fmt(x)}")
                return None
            return tuple(float(c) for c in x)
        if k.kind == "pairs":
            ok = isinstance(x, list) and len(x) >= 2 and all(
                isinstance(p, list) and len(p) == 2 and all(isinstance(c, (int, float)) and not isinstance(c, bool) for c in p) for p in x)
            if not ok:
                self.bad(kp, "must be a list of at least 2 [s, A] number pairs")
                return None
            return [(float(a), float(b)) for a, b in x]
        if k.kind == "strlist":
            if not (isinstance(x, list) and all(isinstance(c, str) for c in x)):
                self.bad(kp, f"must be a list of strings, got {_fmt(x)}")
                return None
            for c in x:
                bad_char = _control_character(c)
                if bad_char:
                    self.bad(kp, f"must not contain control characters or line breaks, got {_fmt(c)} ({bad_char})")
                    return None
            return list(x)
        raise AssertionError(k.kind)  # pragma: no cover

    def array_of_tables(self, raw, schema_name, path):
        if raw is None:
            return []
        if not isinstance(raw, list) or not all(isinstance(t, dict) for t in raw):
            self.bad(path, "must be an array of tables ([[...]])")
            return []
        return [self.section(t, schema_name, f"{path}[{i}]") for i, t in enumerate(raw)]

    # -- the scene -----------------------------------------------------------

    def scene(self, raw):
        sections = {n.split(".")[0] for n in SCHEMA if n}
        for name in raw:
            if name in NOT_YET:
                self.bad(name, NOT_YET[name])
            elif name not in sections and name != "title":
                self.unknown("", name, ["title"] + sorted(sections))
        not_tables = [name for name in sorted(sections) if name in raw and not isinstance(raw[name], dict)]
        for name in not_tables:
            self.bad(name, f"must be a table ([{name}]), got {type(raw[name]).__name__} {_fmt(raw[name])}")
        if not_tables:  # the keys of a section that is not a table would only repeat it as missing keys
            return Scene(title=raw.get("title"), tube=Section.at("tube"), time=Section.at("time"),
                         output=Section.at("output"), environment=Section.at("environment"))
        top = self.section({k: v for k, v in raw.items() if k == "title"}, "", "")
        for req in ("tube", "time"):
            if req not in raw:
                self.bad(req, "missing section (required)")
        # a missing required section is one problem, not one per key inside it
        tube = self.section(raw["tube"], "tube", "tube") if "tube" in raw else Section.at("tube")
        time = self.section(raw["time"], "time", "time") if "time" in raw else Section.at("time")
        output = self.section(raw.get("output", {}), "output", "output")
        env = self.section(raw.get("environment", {}), "environment", "environment")
        wall = fluid = None
        if "wall" in raw:
            rw = raw["wall"]
            wall = self.section({k: v for k, v in rw.items() if k != "perturbation"}, "wall", "wall")
            wall["perturbation"] = self.array_of_tables(rw.get("perturbation"), "wall.perturbation[]", "wall.perturbation")
        if "fluid" in raw:
            rf = raw["fluid"]
            fluid = self.section({k: v for k, v in rf.items() if k not in ("ends", "initial", "perturbation")}, "fluid", "fluid")
            fluid["ends"] = self.section(rf.get("ends", {}), "fluid.ends", "fluid.ends")
            fluid["initial"] = self.array_of_tables(rf.get("initial"), "fluid.initial[]", "fluid.initial")
            fluid["perturbation"] = self.array_of_tables(rf.get("perturbation"), "fluid.perturbation[]", "fluid.perturbation")
        rod = None
        if "rod" in raw:
            rr = raw["rod"]
            rod = self.section({k: v for k, v in rr.items() if k not in ("ends", "initial", "load", "perturbation")}, "rod", "rod")
            for sub in ("ends", "initial", "load"):
                rod[sub] = self.section(rr.get(sub, {}), f"rod.{sub}", f"rod.{sub}")
            rod["perturbation"] = self.array_of_tables(rr.get("perturbation"), "rod.perturbation[]", "rod.perturbation")
        initial = None
        if "initial" in raw:
            ri = raw["initial"]
            for name in ri:
                if name != "traveling_shock":
                    self.unknown("initial", name, ["traveling_shock"])
            if "traveling_shock" in ri:
                ts = self.section(ri["traveling_shock"], "initial.traveling_shock", "initial.traveling_shock")
                initial = Section.at("initial", traveling_shock=ts)
        shock = self.section(raw["shock_capturing"], "shock_capturing", "shock_capturing") if "shock_capturing" in raw else None
        scene = Scene(title=top.get("title"), tube=tube, time=time, output=output, environment=env, wall=wall,
                      fluid=fluid, rod=rod, initial=initial, shock_capturing=shock)
        if not self.problems:
            self.cross_checks(scene)
        return scene

    def cross_checks(self, sc):
        L = sc.tube.length
        R0 = sc.tube.radius
        if sc.wall is None and sc.fluid is None and sc.rod is None:
            self.bad("(scene)", "no effects: add a [rod], [fluid] and/or [wall] section")
        if sc.rod is not None:
            self.rod_checks(sc)
        if sc.tube.area_table is not None:
            self.check_area_table(sc.tube.area_table, L)
            if sc.wall is not None:
                self.bad("tube.area_table", "only for a rigid wall (a scene without [wall])")
        if sc.time.end < sc.time.step:
            self.bad("time.end", f"must be >= time.step ({sc.time.step:g}), got {sc.time.end:g}")
        elif not sc.time.end / sc.time.step <= MAX_STEPS:
            self.bad("time.end", f"time.end / time.step = {sc.time.end:g} / {sc.time.step:g} = {sc.time.end / sc.time.step:.3g} "
                                 f"steps, more than the {_MAX_STEPS_TEXT} a run may take: shorten time.end or lengthen time.step")
        self.gravity_checks(sc)
        if sc.wall is not None:
            self.wall_checks(sc.wall, R0, L)
        if sc.fluid is not None:
            self.fluid_checks(sc.fluid, L, sc)
        env = sc.environment
        if env.external_pressure is None:
            env["external_pressure"] = sc.fluid.pressure if (sc.fluid is not None and sc.fluid.pressure is not None) else 0.0
        if sc.fluid is not None and sc.fluid.model == "incompressible" and sc.fluid.pressure is None:
            sc.fluid["pressure"] = env.external_pressure
        if sc.fluid is not None and sc.fluid.ends.sL == "outflow":  # open ends: the defaults that need the environment
            ends = sc.fluid.ends
            ends["outflow_pressure"] = env.external_pressure if ends.outflow_pressure is None else ends.outflow_pressure
            ends["inflow_pressure"] = sc.fluid.pressure if ends.inflow_pressure is None else ends.inflow_pressure
        if sc.output.fields is not None and sc.rod is None:
            valid = [g for g, on in (("fluid", sc.fluid is not None), ("wall", sc.wall is not None)) if on]
            for f in sc.output.fields:
                if f not in valid:
                    self.bad("output.fields", f"unknown or absent field group {_fmt(f)}; this scene has: {', '.join(valid)}")
        if sc.output.file is not None and not sc.output.file.strip():
            self.bad("output.file", "must not be empty")
        if not self.problems:
            self.derived_checks(sc)
        if sc.initial is not None and sc.initial.traveling_shock is not None and not self.problems:
            self.traveling_shock_checks(sc)
        if sc.shock_capturing is not None:
            self.shock_capturing_checks(sc)

    def gravity_checks(self, sc):
        """A fixed centreline lies along +x: gravity acts on its fluid through g_x alone (Scene.gravity_acts); the other
        components, or gravity on a tube without fluid, would be dropped without a word."""
        g = sc.environment.gravity
        if sc.rod is not None or not any(g):
            return
        if g[1] != 0.0 or g[2] != 0.0:
            self.bad("environment.gravity", f"a straight tube (no [rod]) lies along x and only g_x acts on its fluid; "
                     f"the y and z components of {list(g)} would be dropped: give [g_x, 0, 0] or add a [rod]")
        elif sc.fluid is None:
            self.bad("environment.gravity", "a straight tube without [fluid] has nothing gravity acts on (its wall moves "
                     "radially): remove it, or add a [fluid] or a [rod]")

    def derived_checks(self, sc):
        """Quantities made of several keys must be finite (and masses, sound speeds positive): each key may be a finite
        number while the gas's entropy ln(p / rho^gamma) of a density of 1e300 is not.  A quantity that is not is
        blamed on the most extreme of its keys (the largest |log10|x||), named in one line."""
        import numpy as np

        from .derived import wall_parameters

        val = _ResolvedKeys(sc)
        L, R0 = val("tube.length"), val("tube.radius")
        geometry = ["tube.length", "tube.radius"]
        found = []

        def need(what, x, keys, positive=False):
            x = np.asarray(x, dtype=np.float64)
            if not np.all(np.isfinite(x)) or (positive and not np.all(x > 0.0)):
                found.append((what, keys))

        with np.errstate(all="ignore"):
            need("volume", np.pi * R0 * R0 * L, geometry, positive=True)
            f = sc.fluid
            if f is not None:
                rho0, u = val("fluid.density"), val("fluid.velocity")
                need("mass", rho0 * np.pi * R0 * R0 * L, ["fluid.density"] + geometry, positive=True)
                need("kinetic energy", 0.5 * rho0 * u * u * np.pi * R0 * R0 * L, ["fluid.velocity", "fluid.density"] + geometry)
                if f.model == "ideal-gas":
                    gamma, cv = val("fluid.gamma"), val("fluid.gas_constant") / (val("fluid.gamma") - 1.0)
                    gas = ["fluid.gamma", "fluid.gas_constant"]
                    states = [("fluid.density", "fluid.pressure")]
                    states += [(f"fluid.initial[{i}].density" if r.density is not None else None,
                                f"fluid.initial[{i}].pressure" if r.pressure is not None else None)
                               for i, r in enumerate(f.initial)]
                    S0 = cv * np.log(val("fluid.pressure") / np.power(rho0, gamma))
                    for kr, kp in states:
                        if kr is None and kp is None:
                            continue
                        p = val(kp) if kp else np.exp(S0 / cv) * np.power(val(kr), gamma)
                        rho = val(kr) if kr else np.power(p * np.exp(-S0 / cv), 1.0 / gamma)
                        keys = [k for k in (kr, kp) if k] + ([] if kr and kp else ["fluid.density", "fluid.pressure"]) + gas
                        need("entropy", cv * np.log(p / np.power(rho, gamma)), keys)
                        need("sound speed", np.sqrt(gamma * p / rho), keys, positive=True)
                        need("internal energy", p * np.pi * R0 * R0 * L / (gamma - 1.0), keys + geometry)
                elif f.model == "barotropic":
                    keys = ["fluid.bulk_modulus", "fluid.density", "fluid.gamma"]
                    need("sound speed", np.sqrt(val("fluid.bulk_modulus") / rho0), keys, positive=True)
                    need("internal energy", val("fluid.bulk_modulus") / val("fluid.gamma") * np.pi * R0 * R0 * L,
                         keys + geometry)
            if sc.wall is not None:
                w = wall_parameters(sc.wall, R0)
                keys = [f"wall.{k}" for k in ("a", "beta1", "beta2", "stiffness", "thickness", "density", "youngs_modulus",
                                                "poisson_ratio", "shear_coefficient", "tension")] + geometry
                for name in ("a", "beta1", "beta2", "stiffness"):
                    need(f"wall coefficient {name}", getattr(w, name), keys)
                need("wall's elastic energy scale", (w.beta2 + w.stiffness) * R0 * R0 * L, keys)
        for what, keys in found[:1]:  # one line: the first quantity that fails, on its most extreme key
            key, x = max(((k, val(k)) for k in keys if val(k) is not None and val(k) != 0.0),
                         key=lambda kv: abs(math.log10(abs(kv[1]))), default=(keys[0], val(keys[0])))
            others = [k for k in keys if k != key and val(k) is not None][:2]
            self.bad(key, f"{_num(x)} makes the {what} derived from it (with {', '.join(f'{k} = {_num(val(k))}' for k in others)}) "
                          "overflow or vanish: the quantities derived from a scene's numbers must be finite")

    def shock_capturing_checks(self, sc):
        """``[shock_capturing]`` is energy-exact where every unknown the parcel volumes read carries inertia
        and the heating has a closed form: an ideal gas in a straight tube, rigid (uniform or
        ``tube.area_table``) or with a dynamic wall (linear law or tube law), midpoint scheme
        (varint.terms.shock_capturing); on a [rod] the same walls (area_table aside, which the coupled tube refuses
        anyway), with the energy kept to the coupled scheme's own O(h^2) (varint.terms.coupled_shock_capturing)."""
        kp = "shock_capturing"
        if sc.fluid is None or sc.fluid.model != "ideal-gas":
            self.bad(kp, "needs a [fluid] with model = 'ideal-gas' (the viscous work heats the gas)")
        elif sc.wall is not None and sc.wall.model != "dynamic":
            self.bad(kp, "needs wall.model = 'dynamic' (a quasistatic wall's radii are half-level unknowns, "
                         "for which the energy balance is not exact)")

    def traveling_shock_checks(self, sc):
        """``[initial.traveling_shock]``: a straight tube with a linear wall and an ideal gas at rest, closed ends.

        The traveling wave is solved here (varint.exact.shocks) and handed to the initial fields: the fluid's as
        ``fluid.traveling_shock`` (read by varint.scene.initial), the wall's as an internal entry of
        ``wall.perturbation`` whose profile is the wave's R(s) - R0.
        """
        kp = "initial.traveling_shock"
        ts_keys = sc.initial.traveling_shock
        f, w = sc.fluid, sc.wall
        if f is None or f.model != "ideal-gas":
            self.bad(kp, "needs a [fluid] with model = 'ideal-gas'")
            return
        if w is None or w.law != "linear":
            self.bad(kp, "needs a [wall] with law = 'linear' (the wall law of the paper's traveling wave)")
            return
        if f.ends.s0 == "periodic":
            self.bad(kp, "needs closed ends (the states far ahead and far behind differ)")
        if f.initial or f.perturbation or w.perturbation:
            self.bad(kp, "replaces the initial fields: remove fluid.initial, fluid.perturbation and wall.perturbation")
        if f.velocity != 0.0:
            self.bad("fluid.velocity", "must be 0: the gas ahead of a traveling shock is at rest")
        x0 = ts_keys.position
        if not 0.0 < x0 < sc.tube.length:
            self.bad(f"{kp}.position", f"must lie inside the tube (0, {sc.tube.length:g}), got {x0:g}")
        if self.problems:
            return
        from ..errors import VarintError
        from ..exact.shocks import traveling_shock
        from .derived import tube_of_scene

        try:
            wave = traveling_shock(tube_of_scene(sc), ts_keys.speed)
        except VarintError as exc:
            self.bad(f"{kp}.speed", str(exc))
            return
        f["traveling_shock"] = Section.at("fluid.traveling_shock", wave=wave, position=x0)
        # (every declared key present, as in a perturbation read from the file; the internal shape needs none of them)
        declared = {k.name: None if k.default is REQUIRED else k.default for k in SCHEMA["wall.perturbation[]"]}
        w["perturbation"] = [Section.at("wall.perturbation[0]", declared, field="R", shape="traveling_shock", wave=wave,
                                        position=x0)]

    def rod_checks(self, sc):
        rod = sc.rod
        periodic = rod.ends.s0 == "periodic" or rod.ends.sL == "periodic"
        if periodic:
            ini, load = rod.initial, rod.load
            if rod.ends.s0 != rod.ends.sL:
                self.bad("rod.ends", "periodic must be set at both ends (s0 and sL)")
            elif any(ini.curvature):
                self.bad("rod.initial.curvature", "a periodic rod starts straight along x (its period is L E_1)")
            elif ini.angular_velocity[1] != 0.0 or ini.angular_velocity[2] != 0.0:
                self.bad("rod.initial.angular_velocity", "a periodic rod can only spin about its axis x (another spin "
                         "would move its ends apart)")
            elif any(load.force) or any(load.torque):
                self.bad("rod.load", "a periodic rod has no tip to load")
            elif rod.constraint != "none":
                self.bad("rod.constraint", "a periodic inextensible rod has an indeterminate tension (its length is "
                         "the period): use constraint = 'none'")
            elif ini.shape == "steady_rotation":
                self.bad("rod.initial.shape", "'steady_rotation' is not available for a periodic rod")
        if sc.fluid is not None and (sc.fluid.ends.s0 == "periodic") != periodic:
            self.bad("fluid.ends", "a [fluid] on a [rod] is periodic exactly when the rod is (rod.ends and fluid.ends "
                     "both 'periodic', or neither)")
        held = [e for e in (rod.ends.s0, rod.ends.sL) if e in ("clamped", "pinned")]
        if (sc.fluid is not None and sc.fluid.model == "incompressible" and sc.wall is None
                and sc.fluid.ends.s0 in ("closed", "periodic") and (periodic or len(held) == 2)
                and not any(rod.initial.curvature)):
            # the parcels' volumes fix the tube's length, which the supports (or the period) already fix at first order:
            # the sum of the pressure multipliers is indeterminate and Newton's matrix singular (hydraulic lock)
            self.bad("fluid.model", "an incompressible liquid in a rigid, closed tube that is straight and held at both "
                     "ends (or periodic) has an indeterminate pressure: add a [wall] (e.g. model = 'quasistatic')")
        if (sc.fluid is not None and sc.fluid.model == "incompressible" and sc.wall is None
                and sc.fluid.ends.s0 == "closed"):
            # the parcels keep their volumes in a tube of fixed section and the closed ends hold the first and last
            # labels: the column cannot move along the tube, and the first step would take the velocity (and its
            # kinetic energy) away
            why = ("an incompressible liquid in a closed, rigid tube on a [rod] cannot flow along the tube (its parcels "
                   "keep their volumes and the ends hold the column): give 0, open the ends (fluid.ends) or add a [wall]")
            if sc.fluid.velocity != 0.0:
                self.bad("fluid.velocity", f"{_num(sc.fluid.velocity)} m/s: {why}")
            for i, r in enumerate(sc.fluid.initial):
                if r.velocity is not None and r.velocity != 0.0:
                    self.bad(f"fluid.initial[{i}].velocity", f"{_num(r.velocity)} m/s: {why}")
        if sc.wall is not None and sc.fluid is None:
            self.bad("wall", "a [wall] on a [rod] needs a [fluid] in this version (without one the wall would couple to "
                     "the rod only through p_ext on the tube's volume, which is not implemented)")
        if sc.tube.area_table is not None:
            self.bad("tube.area_table", "not available with a [rod] (the coupled tube has a uniform rigid radius or a [wall])")
        if sc.initial is not None and sc.initial.traveling_shock is not None:
            self.bad("initial.traveling_shock", "needs a straight fixed tube: not available with a [rod]")
        if (rod.constraint == "inextensible_unshearable" and sc.wall is None and sc.fluid is not None
                and sc.fluid.model == "incompressible" and sc.fluid.ends.s0 != "inflow"):
            # (open ends let the liquid through: the inextensible pipe conveying liquid of Paidoussis, theory §13.1)
            self.bad("rod.constraint", "an incompressible liquid in a rigid, closed, inextensible tube cannot move relative "
                     "to it (its volume already fixes the length): add a [wall], open its ends or use constraint = 'none'")
        if rod.constraint == "inextensible_unshearable" and rod.measure == "paper":
            self.bad("rod.measure", "'paper' weights densities by |Gamma|, which the inextensible rod holds at 1: use 'reference'")
        stiff = ("mass_per_length", "rotary_inertia", "bending_stiffness", "torsional_stiffness", "axial_stiffness", "shear_stiffness")
        material = ("youngs_modulus", "density", "thickness")
        given_s = [k for k in stiff if rod[k] is not None]
        given_m = [k for k in material + ("shear_modulus",) if rod[k] is not None]
        if given_s and given_m:
            self.bad(f"rod.{given_m[0]}", "give either the material form or the stiffness form, not both")
        elif given_s:
            # the inextensible, unshearable rod has no axial or shear energy: those two may be left out
            needed = stiff[:4] if rod.constraint == "inextensible_unshearable" else stiff
            for k in needed:
                if rod[k] is None:
                    self.bad(f"rod.{k}", f"missing (the stiffness form needs all {len(needed)} of " + ", ".join(needed) + ")")
        else:
            for k in material:
                if rod[k] is None:
                    self.bad(f"rod.{k}", "missing (material form: youngs_modulus, density, thickness; or the stiffness form)")
        if rod.initial.shape == "steady_rotation" and not any(rod.initial.angular_velocity):
            self.bad("rod.initial.shape", "\"steady_rotation\" needs a nonzero rod.initial.angular_velocity")
        if rod.dimension == 2:
            planar = {"rod.initial.velocity": (rod.initial.velocity, 2), "rod.initial.angular_velocity": (rod.initial.angular_velocity, 0),
                      "rod.initial.curvature": (rod.initial.curvature, 0), "rod.load.force": (rod.load.force, 2),
                      "rod.load.torque": (rod.load.torque, 0), "environment.gravity": (sc.environment.gravity, 2)}
            for key, (vec, kind) in planar.items():
                if vec is None:
                    continue
                out_of_plane = vec[2] != 0.0 if kind == 2 else (vec[0] != 0.0 or vec[1] != 0.0)
                if out_of_plane:
                    what = "a z component" if kind == 2 else "x or y components"
                    self.bad(key, f"a planar rod (dimension = 2) moves in the x-y plane: this vector must not have {what}")
        for i, p in enumerate(rod.perturbation):
            kp = f"rod.perturbation[{i}]"
            self.shape_checks(p, kp, L=sc.tube.length, allowed=("velocity",))
            d = p.direction
            if not any(d):
                self.bad(f"{kp}.direction", "must not be zero")
            elif rod.dimension == 2 and d[2] != 0.0:
                self.bad(f"{kp}.direction", "a planar rod (dimension = 2) moves in the x-y plane: this vector must not have a z component")
        if sc.output.fields is not None:
            valid = ["rod"] + [g for g, on in (("fluid", sc.fluid is not None), ("wall", sc.wall is not None)) if on]
            for f in sc.output.fields:
                if f not in valid:
                    self.bad("output.fields", f"unknown or absent field group {_fmt(f)}; this scene has: {', '.join(valid)}")

    def check_area_table(self, table, L):
        s = [p[0] for p in table]
        if any(b <= a for a, b in zip(s, s[1:])):
            self.bad("tube.area_table", "s values must be strictly increasing")
        if s[0] > 0 or s[-1] < L:
            self.bad("tube.area_table", f"must cover the tube [0, {L:g}], covers [{s[0]:g}, {s[-1]:g}]")
        if any(p[1] <= 0 for p in table):
            self.bad("tube.area_table", "areas must be > 0")

    def wall_checks(self, w, R0, L):
        material = ("thickness", "youngs_modulus")
        if w.model == "quasistatic" and w.a is not None:
            self.bad("wall.a", "a quasistatic wall has no inertia (a = 0); remove the key or use model = 'dynamic'")
        if w.model == "dynamic" and w.a is None and (w.thickness is None or w.density is None):
            self.bad("wall.a", "missing: give a, or thickness and density")
        if w.law == "linear":
            for k in ("stiffness",):
                if w[k] is not None:
                    self.bad(f"wall.{k}", "belongs to law = 'tube-law', not 'linear'")
            if w.beta2 is None and any(w[k] is None for k in material):
                self.bad("wall.beta2", "missing: give beta2, or thickness and youngs_modulus")
            if w.beta1 is None and any(w[k] is None for k in material):
                self.bad("wall.beta1", "missing: give beta1, or thickness and youngs_modulus")
        else:
            for k in ("beta1", "beta2"):
                if w[k] is not None:
                    self.bad(f"wall.{k}", "belongs to law = 'linear', not 'tube-law'")
            if w.stiffness is None and any(w[k] is None for k in material):
                self.bad("wall.stiffness", "missing: give stiffness, or thickness and youngs_modulus")
        for i, p in enumerate(w.perturbation):
            self.shape_checks(p, f"wall.perturbation[{i}]", L, allowed=("R",))

    def fluid_checks(self, f, L, sc):
        model = f.model
        if model == "ideal-gas":
            f["gamma"] = 1.4 if f.gamma is None else f.gamma
            if f.gamma <= 1.0:
                self.bad("fluid.gamma", f"must be > 1 for an ideal gas, got {f.gamma:g}")
        elif model == "barotropic":
            f["gamma"] = 7.15 if f.gamma is None else f.gamma
            if f.bulk_modulus is None:
                self.bad("fluid.bulk_modulus", "missing (required for model = 'barotropic')")
        elif f.gamma is not None:
            self.bad("fluid.gamma", "not used by an incompressible fluid; remove it")
        if model != "incompressible":
            if f.pressure is None:
                self.bad("fluid.pressure", f"missing (required for model = '{model}')")
            elif f.pressure <= 0 and model == "ideal-gas":
                self.bad("fluid.pressure", f"must be > 0 for an ideal gas, got {f.pressure:g}")
        if model == "incompressible" and sc.wall is None and sc.rod is None and f.ends.s0 != "inflow":
            self.bad("fluid.model", "an incompressible fluid in a rigid straight tube cannot move (every parcel volume is "
                     "fixed); add a [wall] or a [rod]")
        if model != "barotropic" and f.bulk_modulus is not None:
            self.bad("fluid.bulk_modulus", f"not used by model = '{model}'; remove it")
        e0, e1 = f.ends.s0, f.ends.sL
        self.open_end_checks(f, sc)
        if (e0 == "periodic") != (e1 == "periodic"):
            self.bad("fluid.ends", "periodic must be set at both ends (s0 and sL)")
        for i, r in enumerate(f.initial):
            kp = f"fluid.initial[{i}]"
            if not (0.0 <= r["from"] < r["to"] <= L):
                self.bad(kp, f"needs 0 <= from < to <= {L:g}, got from = {r['from']:g}, to = {r['to']:g}")
            if model == "barotropic" and r.density is not None and r.pressure is not None:
                self.bad(kp, "a barotropic fluid takes density or pressure in a region, not both")
            if model == "incompressible" and (r.density is not None or r.pressure is not None):
                self.bad(kp, "an incompressible fluid takes only velocity in initial regions")
        allowed = ("velocity",) if model == "incompressible" else ("pressure", "density", "velocity")
        for i, p in enumerate(f.perturbation):
            self.shape_checks(p, f"fluid.perturbation[{i}]", L, allowed=allowed)

    def open_end_checks(self, f, sc):
        """``fluid.ends = { s0 = "inflow", sL = "outflow" }`` (docs/theory.md §13): both ends open or neither; the
        inlet's state defaults to the scene's fluid.velocity / density / pressure, the outlet's pressure to the
        external pressure (a free jet)."""
        e = f.ends
        opened = e.s0 == "inflow" or e.sL == "outflow"
        inlet_keys = ("inflow_velocity", "inflow_density", "inflow_pressure", "outflow_pressure", "windkessel_R1",
                      "windkessel_C", "windkessel_R2")
        if not opened:
            for k in inlet_keys:
                if e[k] is not None:
                    self.bad(f"fluid.ends.{k}", "only for open ends (s0 = 'inflow', sL = 'outflow')")
            for k, default in (("inflow", "velocity"), ("outflow", "pressure")):
                if e[k] != default:
                    self.bad(f"fluid.ends.{k}", "only for open ends (s0 = 'inflow', sL = 'outflow')")
            return
        for k in ("windkessel_R1", "windkessel_C", "windkessel_R2"):
            if (e[k] is None) == (e.outflow == "windkessel"):
                self.bad(f"fluid.ends.{k}", "missing (required for outflow = 'windkessel')" if e[k] is None else
                         "only for outflow = 'windkessel'")
        if e.s0 != "inflow" or e.sL != "outflow":
            self.bad("fluid.ends", "open ends come in a pair in this version: s0 = 'inflow' and sL = 'outflow'")
            return
        velocity_key = "fluid.ends.inflow_velocity" if e.inflow_velocity is not None else "fluid.velocity"
        if e.inflow_velocity is None:
            e["inflow_velocity"] = f.velocity
        if e.inflow_density is None:
            e["inflow_density"] = f.density
        if e.inflow_pressure is None:
            e["inflow_pressure"] = f.pressure
        if e.inflow == "velocity" and not e.inflow_velocity > 0.0:
            self.bad(velocity_key, f"a velocity inlet needs fluid flowing in (> 0), got {e.inflow_velocity:g} m/s")
        if f.model == "incompressible" and e.inflow_density != f.density:
            self.bad("fluid.ends.inflow_density", "an incompressible fluid has one density: remove it")
        if f.model == "ideal-gas" and e.inflow_pressure is not None and e.inflow_pressure <= 0.0:
            self.bad("fluid.ends.inflow_pressure", f"must be > 0 for an ideal gas, got {e.inflow_pressure:g}")

    def shape_checks(self, p, kp, L, allowed):
        if p.field not in allowed:
            self.bad(f"{kp}.field", f"{_fmt(p.field)} cannot be perturbed here; choose one of {', '.join(allowed)}")
        need = {"cosine": ("wavelength",), "gaussian": ("center", "width"), "step": ("from", "to")}[p.shape]
        for n in need:
            if p[n] is None:
                self.bad(f"{kp}.{n}", f"missing (required for shape = '{p.shape}')")
        others = {"wavelength", "center", "width", "from", "to"} - set(need)
        for n in sorted(others):
            if p[n] is not None:
                self.bad(f"{kp}.{n}", f"not used by shape = '{p.shape}'")
        if p.shape == "step" and p["from"] is not None and p["to"] is not None and not p["from"] < p["to"]:
            self.bad(f"{kp}.to", f"must be > from ({p['from']:g}), got {p['to']:g}")
        elif L is not None and p.shape == "step" and p["from"] is not None and p["to"] is not None:
            if p["from"] >= L or p["to"] <= 0.0:
                self.bad(f"{kp}.from", f"the interval [{p['from']:g}, {p['to']:g}] m does not meet the tube [0, {L:g}] m")
        if L is not None and p.shape == "gaussian" and p.center is not None and not 0.0 <= p.center <= L:
            self.bad(f"{kp}.center", f"must lie on the tube [0, {L:g}] m (its arc length s), got {p.center:g}")
