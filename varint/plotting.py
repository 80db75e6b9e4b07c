"""PNG figures of a run file: monitors against time, and the fields.

Tubes: space-time maps of p, u and R, each on a diverging colour scale centred on the undisturbed state
(a single record: profiles over s instead).  Rods: centreline snapshots in side and end views (a static
file: the shape against the straight unloaded rod), a deflection too small to see at true scale drawn on
its own scale, with the displacement of the node that moves most and the rotation of the sections about
their own axis against time (a shaft spinning on its axis moves only there).  A single record draws
markers.

The pure functions (:func:`monitor_panels`, :func:`energy_scale`, :func:`log_floor`, :func:`undisturbed`,
:func:`diverging_limits`, :func:`rod_deflection`, :func:`rod_view_mode`, :func:`section_twist`) carry the
choices; :func:`plot_run` only draws them.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .run.io import energy_motion_scale, read_run

__all__ = ["plot_run", "plot_profiles", "animate_run", "monitors_figure", "fields_figure", "profiles_figure",
           "animation_figure", "monitor_panels", "Panel", "declared_invariants", "energy_scale", "log_floor",
           "undisturbed", "plateaus", "ColourScale", "colour_scale", "reference_value", "diverging_limits",
           "exact_profiles", "ExactProfiles", "nearest_records", "gravity_in_view", "draw_gravity", "rod_deflection",
           "rod_view_mode", "section_twist", "centreline_frames"]

EPS = np.finfo(float).eps

# rod deflections below this fraction of the length are drawn on their own scale (um, mm) ...
VISIBLE_FRACTION = 0.05
# ... unless they are at round-off (relative to the length), which is never magnified
ROUNDOFF_FRACTION = 1e-9


class Panel(tuple):
    """One monitor panel: the pair ``(label, curves)`` (curves: ``[(name, values), ...]``) with how to draw it.

    ``yscale`` is "linear" or "log"; on a log axis values below ``floor`` (a round-off level, not zero) are
    drawn at it, and ``skip_first`` leaves out the first record (a change from the first record, zero by
    definition).  ``note`` is written in the panel (e.g. the energy scale).
    """

    def __new__(cls, label, curves, yscale="linear", floor=None, floor_label="", skip_first=False, note=""):
        self = super().__new__(cls, (label, curves))
        self.yscale, self.floor, self.floor_label, self.skip_first, self.note = yscale, floor, floor_label, skip_first, note
        return self

    @property
    def label(self):
        return self[0]

    @property
    def curves(self):
        return self[1]


def _term_name(key):
    return "kinetic" if key == "kinetic_energy" else key.replace("energy_", "")


def energy_scale(mon):
    """(scale [J], what it is) for the energy error (E - E0) / scale: the energy that moves, the largest kinetic
    energy plus the largest change of the potential energy (:func:`varint.run.io.energy_motion_scale`, as
    ``varint info`` reports it), never ``|E0|``, which a gas's internal energy or a liquid's p V dominates.
    ``(1.0, None)`` when nothing moves (the error is then plotted in joules).
    """
    scale = energy_motion_scale(mon["energy"], mon.get("kinetic_energy"))
    if scale > 0:
        return scale, "(max K + range of U)"
    return 1.0, None


def log_floor(scale):
    """Round-off floor ``eps * max|scale|`` of a quantity of that size (None when it is zero)."""
    s = float(np.max(np.abs(scale))) if np.size(scale) else 0.0
    return EPS * s if s > 0 else None


def monitor_panels(mon, invariants=None, geometry=None):
    """[Panel(label, curves), ...] for a run's monitors (each Panel is also the pair ``(label, curves)``).

    Tube runs: energy and mass errors, the fluid's axial momentum, Newton iterations.  Rod runs
    (they have ``frame_orthogonality``): energy error and terms, the changes of linear momentum and of
    angular momentum about the centre of mass (reactions of supports included), frame
    orthogonality, Newton iterations.  The energy error is relative to :func:`energy_scale`; the changes
    of momenta and the orthogonality defect go on log axes floored at round-off of their own size.

    ``invariants``: the names the model declares (:func:`declared_invariants`, as ``varint check`` lists them);
    given, a rod's momentum panels are those of the declared invariants only (a clamped hose keeps neither
    momentum; a shaft on bearings keeps its angular momentum about the bearing axis, a rod under gravity its
    momenta across and along it), and a declared ``mass`` gets its panel.  ``geometry``: ``{"gravity": g,
    "axis": (point, unit vector)}`` for those projections.

    A single record (a static file) has no errors or changes, which are zero by definition: its panels
    are the values at that instant (energy and its terms, the momenta, the orthogonality defect).
    """
    def change(y):
        return np.linalg.norm(y - y[0], axis=1)

    records = len(next(iter(mon.values()))) if mon else 0
    if records == 1:
        return _single_record_panels(mon)
    panels = []
    if "energy_balance" in mon:  # open ends (docs/theory.md §13.4): the balances, not the conservation laws
        scale = max(float(np.max(np.abs(mon["energy"]))), float(np.max(np.abs(mon["energy_flux"]))), 1e-300)
        panels.append(Panel("energy balance (E - E0 - flux) / max(|E|, |flux|)", [("energy", mon["energy_balance"] / scale)],
                            note=f"boundary energy flux at the end: {mon['energy_flux'][-1]:.3g} J"))
        pscale = max(float(np.max(np.abs(mon["linear_momentum"]))), float(np.max(np.abs(mon["momentum_flux"]))), 1e-300)
        panels.append(Panel("momentum balance (P - P0 - flux) / max(|P|, |flux|)",
                            [("x", mon["momentum_balance"][:, 0] / pscale)]))
        panels.append(Panel("mass balance (m - m0 - flux) / m0", [("mass", mon["mass_balance"] / abs(mon["mass"][0]))]))
        panels.append(Panel("parcels in the tube", [("parcels", mon["parcels"])]))
        if "newton_iterations" in mon:
            panels.append(Panel("Newton iterations", [("per step", mon["newton_iterations"])], skip_first=True))
        return panels
    if "energy" in mon:
        scale, what = energy_scale(mon)
        dE = mon["energy"] - mon["energy"][0]
        if what is None:
            panels.append(Panel("energy error E - E0 [J]", [("energy", dE)]))
        else:
            note = f"{what} = {scale:.3g} J\n(|E0| = {abs(mon['energy'][0]):.2g} J)"
            panels.append(Panel(f"energy error (E - E0) / {what}", [("energy", dE / scale)], note=note))
    if "frame_orthogonality" in mon:
        panels.append(Panel("energy terms [J]", _energy_terms(mon)))
        if invariants is not None and "mass" in invariants and "mass" in mon:
            m = mon["mass"]
            panels.append(Panel("relative mass error (m - m0) / m0", [("mass", (m - m[0]) / (abs(m[0]) or 1.0))]))
        for label, name, sym, y, size in _momentum_changes(mon, invariants, geometry or {}):
            floor = log_floor(np.concatenate([size, y]))
            panels.append(Panel(label, [(name, y)], yscale="log" if floor else "linear", floor=floor,
                                floor_label=f"eps max|{sym}|", skip_first=True))
        panels.append(Panel("frame orthogonality |L^T L - I|", [("max over nodes", mon["frame_orthogonality"])],
                            yscale="log", floor=EPS, floor_label="eps"))
    else:
        if "mass" in mon:
            m = mon["mass"]
            ref = abs(m[0]) if m[0] != 0 else 1.0
            panels.append(Panel("relative mass error (m - m0) / m0", [("mass", (m - m[0]) / ref)]))
        if "linear_momentum" in mon:
            panels.append(Panel("fluid momentum [kg m/s]", [("x", mon["linear_momentum"][:, 0])]))
    if "newton_iterations" in mon:  # the first record has no step before it
        panels.append(Panel("Newton iterations", [("per step", mon["newton_iterations"])], skip_first=True))
    return panels


def _momentum_changes(mon, invariants, geometry):
    """[(label, curve name, symbol, change (K,), size (K,)), ...]: the momenta a rod's model keeps (all of them when
    ``invariants`` is None) as changes from the first record, with the size of the quantity (its round-off level)."""
    P, J, Jcm = mon.get("linear_momentum"), mon.get("angular_momentum"), mon.get("angular_momentum_cm")
    out = []

    def vec(label, name, sym, v):
        out.append((label, name, sym, np.linalg.norm(v - v[0], axis=1), np.linalg.norm(v, axis=1)))

    def comp(label, name, sym, c):
        out.append((label, name, sym, np.abs(c - c[0]), np.abs(c)))

    g = np.asarray(geometry.get("gravity", (0.0, 0.0, 0.0)), dtype=float)
    gn = float(np.linalg.norm(g))
    for inv in (["linear_momentum", "angular_momentum"] if invariants is None else invariants):
        if inv == "linear_momentum" and P is not None:
            vec("change of linear momentum [kg m/s]", "|P - P0|", "P", P)
        elif inv == "angular_momentum" and (Jcm is not None or J is not None):
            if Jcm is not None:
                vec("change of angular momentum [kg m2/s]", "|J_cm - J_cm0|", "J_cm", Jcm)
            else:
                vec("change of angular momentum [kg m2/s]", "|J - J0|", "J", J)
        elif inv == "linear_momentum_transverse_to_gravity" and P is not None and gn > 0:
            e = g / gn
            vec("change of linear momentum across gravity [kg m/s]", "|P_perp - P_perp0|", "P", P - np.outer(P @ e, e))
        elif inv == "angular_momentum_along_gravity" and J is not None and gn > 0:
            comp("change of angular momentum along gravity [kg m2/s]", "|g.(J - J0)|/|g|", "J", J @ (g / gn))
        elif inv in ("angular_momentum_about_the_bearing_axis", "angular_momentum_along_the_period") \
                and J is not None and P is not None and "axis" in geometry:
            a, e = (np.asarray(v, dtype=float) for v in geometry["axis"])
            what = "the bearing axis" if "bearing" in inv else "the period"
            comp(f"change of angular momentum about {what} [kg m2/s]", f"|e.(J_a - J_a0)|, e along {what}", "J",
                 (J - np.cross(a, P)) @ e)
    return out


def _energy_terms(mon):
    keys = ["kinetic_energy"] + sorted(k for k in mon if k.startswith("energy_"))
    return [(_term_name(k), mon[k]) for k in keys if k in mon and np.any(mon[k])]


def _single_record_panels(mon):
    panels = []
    if "energy" in mon:
        panels.append(Panel("energy and its terms [J]", [("total", mon["energy"])] + _energy_terms(mon)))
    for key, label, name in (("linear_momentum", "linear momentum [kg m/s]", "|P|"),
                             ("angular_momentum_cm", "angular momentum [kg m2/s]", "|J_cm| (about the centre of mass)")):
        if key in mon:
            panels.append(Panel(label, [(name, np.linalg.norm(mon[key], axis=1))]))
    if "frame_orthogonality" in mon:
        panels.append(Panel("frame orthogonality |L^T L - I|", [("max over nodes", mon["frame_orthogonality"])]))
    if "mass" in mon:
        panels.append(Panel("mass [kg]", [("mass", mon["mass"])]))
    return panels


def undisturbed(y0, zero_if_below=1e-6):
    """The undisturbed value of a field from its first record: the median over the tube.

    A localised pulse does not move the median (the mean of a pressure pulse would); a value smaller than
    ``zero_if_below`` times the field's range is the tails of a pulse on a state at rest, and is 0.
    """
    y0 = np.asarray(y0, dtype=float)
    y0 = y0[np.isfinite(y0)]  # open ends: inactive slots are NaN (docs/output.md)
    if not y0.size:
        return 0.0
    med = float(np.median(y0))
    span = float(np.max(np.abs(y0 - med))) if y0.size else 0.0
    return 0.0 if abs(med) <= zero_if_below * span else med


def diverging_limits(y):
    """(centre, half width) of a diverging colour scale for a field y (K, n): centred on the undisturbed
    state (:func:`undisturbed` of the first record), symmetric, wide enough for every value."""
    y = np.asarray(y, dtype=float)
    ref = undisturbed(y[0])
    half = float(np.nanmax(np.abs(y - ref))) if np.any(np.isfinite(y)) else 0.0
    return ref, (half if half > 0 else 1.0)


def plateaus(y0, tol=1e-6, share=0.1):
    """The constant states of a profile: values that at least ``share`` of its finite points hold to ``tol`` times
    its range (sorted).  A localised pulse on a state at rest has one (its tails); a Riemann problem two."""
    y0 = np.asarray(y0, dtype=float)
    y0 = np.sort(y0[np.isfinite(y0)])
    if y0.size < 2:
        return [float(v) for v in y0]
    span = float(y0[-1] - y0[0])
    if span == 0.0:
        return [float(y0[0])]
    out, start = [], 0
    for i in range(1, y0.size + 1):  # runs of sorted values whose neighbours differ by at most tol * span
        if i == y0.size or y0[i] - y0[i - 1] > tol * span:
            if i - start >= share * y0.size:
                out.append(float(np.median(y0[start:i])))
            start = i
    return out


class ColourScale:
    """How a space-time map is coloured: ``kind`` "diverging" (``centre``, ``half``: a symmetric scale about the
    undisturbed state) or "sequential" (``vmin``, ``vmax``: the data's range, when the first record has no single
    undisturbed state); ``what`` says where the centre or the range comes from."""

    def __init__(self, kind, what, centre=0.0, half=1.0, vmin=0.0, vmax=1.0):
        self.kind, self.what, self.centre, self.half, self.vmin, self.vmax = kind, what, centre, half, vmin, vmax

    def __repr__(self):
        return f"ColourScale({self.kind!r}, {self.what!r}, centre={self.centre}, half={self.half}, vmin={self.vmin}, vmax={self.vmax})"


def reference_value(scene, key):
    """The undisturbed value of a tube field from the stored scene (a TOML table): ``(value, its key, always)`` or
    None.  The wall radius's is the scene's reference radius ``tube.radius`` (``always``: R - R0 is the wall's
    deflection, whatever the initial data); the fluid's are its initial state ``fluid.pressure`` (a gas),
    ``fluid.density`` (a gas), ``fluid.velocity``, which [[fluid.initial]] regions and perturbations disturb."""
    tube, fluid = scene.get("tube", {}), scene.get("fluid")
    if key == "R":
        r = tube.get("radius")
        return (float(r), "tube.radius", True) if isinstance(r, (int, float)) else None
    if not isinstance(fluid, dict):
        return None
    gas = fluid.get("model") in ("ideal-gas", "barotropic")
    if key == "velocity":
        return float(fluid.get("velocity", 0.0)), "fluid.velocity", False
    if key in ("pressure", "density") and gas and isinstance(fluid.get(key), (int, float)):
        return float(fluid[key]), f"fluid.{key}", False
    return None


def colour_scale(y, reference=None, t0=0.0):
    """The :class:`ColourScale` of a field y (K, n).

    Diverging, centred on the undisturbed state: ``reference`` (:func:`reference_value`), else the first record's
    median (:func:`undisturbed`).  Sequential over the data's range when the first record holds two or more constant
    states (:func:`plateaus`: a Riemann problem, a traveling shock between its far states) and the reference is not
    one that always applies: a centre between them would saturate both states and hide the waves between."""
    y = np.asarray(y, dtype=float)
    finite = np.isfinite(y)
    if not np.any(finite):
        return ColourScale("diverging", "no finite value", 0.0, 1.0)
    states = plateaus(y[0])
    if len(states) >= 2 and not (reference is not None and reference[2]):
        lo, hi = float(np.nanmin(y)), float(np.nanmax(y))
        if hi == lo:
            hi = lo + 1.0
        return ColourScale("sequential", f"{len(states)} states at t = {t0:.3g} s ("
                           + " | ".join(f"{v:.4g}" for v in states) + "): the full range", vmin=lo, vmax=hi)
    if reference is not None:
        ref, what = reference[0], reference[1]
    else:
        ref, what = undisturbed(y[0]), f"median at t = {t0:.3g} s"
    half = float(np.nanmax(np.abs(y - ref)))
    return ColourScale("diverging", what, ref, half if half > 0 else 1.0)


def rod_view_mode(amplitude, length):
    """How to draw a centreline whose largest transverse deflection from its chord is ``amplitude``.

    "true": visible at true scale (at least ``VISIBLE_FRACTION`` of ``length``): positions in metres, equal
    axes.  "deflection": too small to see (a whirling shaft, a small vibration): the deflection itself on
    its own scale (um, mm) against the position along the chord, magnified ``length / amplitude`` times
    relative to true scale.  "rest": at round-off (below ``ROUNDOFF_FRACTION`` of the length): the
    centreline does not move, and magnifying would only draw round-off.
    """
    if not (length > 0) or amplitude >= VISIBLE_FRACTION * length:
        return "true"
    return "rest" if amplitude <= ROUNDOFF_FRACTION * length else "deflection"


def _chord_frame(r0):
    """Unit chord e of the first record's centreline and two transverse unit vectors (e2, e3).

    For a chord along +x these are +y and +z, so projections keep the lab axes' names.
    """
    e = r0[-1] - r0[0]
    n = np.linalg.norm(e)
    e = e / n if n > 0 else np.array([1.0, 0.0, 0.0])
    up = np.array([0.0, 0.0, 1.0]) if abs(e[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e2 = np.cross(up, e)
    e2 /= np.linalg.norm(e2)
    return e, e2, np.cross(e, e2)


def rod_deflection(r):
    """Transverse deflection of the centreline from the straight chord of the first record.

    ``r``: (K, N+1, 3) node positions.  The chord joins the first record's end nodes: for a rod between
    bearings it is the bearing line, for a rod started straight it is that line.  Returns
    ``(along, w, frame)``: the coordinate along the chord (K, N+1), the transverse deflection (K, N+1, 2)
    in the frame's (e2, e3) components, and frame = (origin, e, e2, e3).  A rigid spin about the chord leaves
    w = 0; a whirl of amplitude a makes ``|w| ~ a``.
    """
    r = np.asarray(r, dtype=float)
    o = r[0, 0]
    e, e2, e3 = _chord_frame(r[0])
    d = r - o
    return d @ e, np.stack([d @ e2, d @ e3], axis=-1), (o, e, e2, e3)


def section_twist(Lam):
    """Rotation angle [rad] of each section about its own axis since the first record.

    ``Lam``: (K, N+1, 3, 3) frames whose first column is the section's axis (the reference rod lies along
    +x).  Between consecutive records the body rotation R = Lam_k^T Lam_(k+1) is split into a swing of the
    axis and a twist about it (2 atan2(R_21 - R_12, 1 + tr R)); the twists are summed, i.e. the spin
    rate about the axis integrated in time, which stays well defined while the axis itself swings round
    (a tumbling rod).  Needs less than half a turn between records.  Returns (K, N+1).
    """
    Lam = np.asarray(Lam, dtype=float)
    R = np.einsum("knji,knjl->knil", Lam[:-1], Lam[1:])
    dth = 2.0 * np.arctan2(R[..., 2, 1] - R[..., 1, 2], 1.0 + np.trace(R, axis1=-2, axis2=-1))
    return np.concatenate([np.zeros((1, Lam.shape[1])), np.cumsum(dth, axis=0)])


# -- drawing ---------------------------------------------------------------------------------------------

def _scene(run):
    """The scene table stored in the run file (empty if absent or unreadable)."""
    import tomllib

    try:
        return tomllib.loads(run["attrs"].get("scene_toml", ""))
    except (tomllib.TOMLDecodeError, TypeError):
        return {}


def _time_axis(t):
    """(factor, label) showing times in s, ms or us."""
    T = float(np.max(np.abs(t))) if len(t) else 0.0
    if T == 0.0:
        return 1.0, "t [s]"
    for f, u in ((1.0, "s"), (1e3, "ms"), (1e6, "\u00b5s")):
        if T * f >= 1.0 or f == 1e6:
            return f, f"t [{u}]"
    return 1.0, "t [s]"


def _length_unit(a):
    """(factor, unit) showing lengths of size a in m, mm, um or nm."""
    for f, u in ((1.0, "m"), (1e3, "mm"), (1e6, "\u00b5m"), (1e9, "nm")):
        if a * f >= 1.0:
            return f, u
    return 1e9, "nm"


def _monitors_figure(t, panels, title):
    from matplotlib.figure import Figure
    from matplotlib.ticker import LogLocator, MaxNLocator, NullFormatter

    single = len(t) == 1
    tf, tlabel = _time_axis(t)
    ncol = 3 if len(panels) > 4 else 2
    nrow = max(1, math.ceil(len(panels) / ncol))
    fig = Figure(figsize=(5 * ncol, 3.4 * nrow + 0.3), layout="constrained")
    axes = fig.subplots(nrow, ncol, squeeze=False)
    for ax in axes.flat[len(panels):]:
        ax.set_visible(False)
    for ax, panel in zip(axes.flat, panels):
        label, curves = panel
        log = panel.yscale == "log" and not single
        lows, highs = [], []
        for name, y in curves:
            y = np.asarray(y, dtype=float)
            if single:  # one record (a static file): a marker per quantity, with its value
                i = len(lows)
                lows.append(name)
                ax.plot([i], y[:1], "o", ms=7, color=f"C{i}")
                ax.annotate(f"{y[0]:.4g}", (i, y[0]), xytext=(7, 0), textcoords="offset points", va="center", fontsize=8)
                continue
            tt = t * tf
            if panel.skip_first and len(t) > 2:
                tt, y = tt[1:], y[1:]
            if log:
                y = np.maximum(y, panel.floor)
                lows.append(float(np.min(y)))
                highs.append(float(np.max(y)))
            ax.plot(tt, y, lw=1, label=name)
        near_floor = False
        if log:
            ax.set_yscale("log")
            lo, hi = min(lows), max(highs)
            near_floor = lo < 1e3 * panel.floor  # show the round-off floor only when the data come near it
            if near_floor:
                ax.axhline(panel.floor, color="0.4", ls=":", lw=1,
                           label=f"{panel.floor_label} = {panel.floor:.2g} (smaller values drawn here)")
                lo = min(lo, panel.floor)
            # whole decades (at least one, so there are labelled ticks), at most 5 labelled ticks
            ax.set_ylim(10.0 ** math.floor(math.log10(lo) - 1e-9), 10.0 ** math.ceil(math.log10(hi) + 1e-9))
            ax.yaxis.set_major_locator(LogLocator(base=10, numticks=5))
            ax.yaxis.set_minor_formatter(NullFormatter())
        if single:
            ax.set_xticks(range(len(lows)), lows, fontsize=8, rotation=20 if len(lows) > 3 else 0)
            ax.set_xlim(-0.6, len(lows) - 0.4)
            ax.axhline(0.0, color="0.7", lw=0.8)
        elif len(curves) > 1 or near_floor:
            ax.legend(fontsize=7, loc="best")
        if label.startswith("Newton") and not single:
            ax.set_ylim(0, max(float(np.max(c[1])) for c in curves) + 1)
            ax.yaxis.set_major_locator(MaxNLocator(integer=True))
        if panel.note:
            ax.text(0.02, 0.97, panel.note, transform=ax.transAxes, va="top", ha="left", fontsize=7,
                    bbox=dict(boxstyle="round,pad=0.2", fc="white", ec="0.8", alpha=0.85))
        ax.set_xlabel(f"at t = {t[0]:.4g} s" if single else tlabel)
        ax.set_ylabel(label, fontsize=9)
        ax.grid(alpha=0.3)
        ax.grid(alpha=0.12, which="minor") if log else None
    fig.suptitle(title + ("\none record: the values at that instant" if single else ""), fontsize=10)
    return fig


def _tube_maps(fld, scene):
    """[(name, symbol, unit, x (K, n), values (K, n), field key), ...] for the tube's fields: p, rho (a compressible
    fluid: the contact of a Riemann problem shows only there), u, R."""
    maps = []
    L = float(scene.get("tube", {}).get("length", 0.0))
    if "fluid/pressure" in fld:
        s = fld["fluid/s"]
        L = L or float(s[0, -1] - s[0, 0])
        xc = 0.5 * (s[:, 1:] + s[:, :-1])
        maps.append(("pressure", "p", "Pa", xc, fld["fluid/pressure"], "pressure"))
        rho = fld.get("fluid/density")
        if rho is not None and np.any(np.isfinite(rho)) and np.nanmax(rho) > np.nanmin(rho):  # not a liquid's constant
            maps.append(("density", "\u03c1", "kg/m\u00b3", xc, rho, "density"))
        maps.append(("velocity", "u", "m/s", s, fld["fluid/velocity"], "velocity"))
    if "wall/R" in fld:
        R = fld["wall/R"]
        x = np.linspace(0.0, L or 1.0, R.shape[1])[None, :] * np.ones((R.shape[0], 1))
        maps.append(("wall radius", "R", "m", x, R, "R"))
    return maps


def _interp_finite(xg, x, y):
    """np.interp over the finite points of (x, y) (NaN where there are fewer than two)."""
    ok = np.isfinite(x) & np.isfinite(y)
    if np.count_nonzero(ok) < 2:
        return np.full(len(xg), np.nan)
    return np.interp(xg, x[ok], y[ok], left=np.nan, right=np.nan)


def _tube_figure(t, maps, title, scene=None):
    from matplotlib.figure import Figure

    scene = scene or {}
    single = len(t) == 1
    tf, tlabel = _time_axis(t)
    fig = Figure(figsize=(4.4 * len(maps), 4.0 if single else 4.4), layout="constrained")
    axes = fig.subplots(1, len(maps), squeeze=False)
    for ax, (name, sym, unit, x, y, key) in zip(axes[0], maps):
        sc = colour_scale(y, reference_value(scene, key), float(t[0]))
        f = 1.0
        if sc.kind == "diverging" and unit == "m":  # a wall moving by a fraction of a millimetre: in mm or um
            f, unit = _length_unit(sc.half)
        if sc.kind == "sequential":
            dy, ref = y, 0.0
            lab = f"{sym} [{unit}]"
            what = f"{name}; {sc.what}"
        else:
            ref = sc.centre
            dy = f * (y - ref)
            lab = f"{sym} [{unit}]" if ref == 0.0 else f"{sym} - {sym}0 [{unit}]"
            ref_unit = "m" if f != 1.0 else unit
            what = (f"{name}; undisturbed {sym}0 = 0" + (f" ({sc.what})" if sc.what else "") if ref == 0.0
                    else f"{name}; {sym}0 = {ref:.6g} {ref_unit} ({sc.what})")
        if single:  # one record: the profile
            ax.plot(x[0], dy[0], "-", lw=1.2, marker="." if np.count_nonzero(np.isfinite(x[0])) <= 60 else None)
            if sc.kind == "diverging":
                ax.axhline(0.0, color="0.5", lw=0.8)
            ax.set_ylabel(lab)
            ax.grid(alpha=0.3)
        else:
            # open ends: inactive slots are NaN and the labels move through the tube: interpolate the active ones
            xg = np.linspace(np.nanmin(x), np.nanmax(x), max(200, y.shape[1]))
            img = np.array([_interp_finite(xg, xi, yi) for xi, yi in zip(x, dy)])
            if sc.kind == "sequential":
                im = ax.pcolormesh(xg, t * tf, img, shading="auto", cmap="viridis", vmin=sc.vmin, vmax=sc.vmax)
            else:
                vmax = f * sc.half
                im = ax.pcolormesh(xg, t * tf, img, shading="auto", cmap="RdBu_r", vmin=-vmax, vmax=vmax)
            fig.colorbar(im, ax=ax, label=lab)
            ax.set_ylabel(tlabel)
        ax.set_title(what, fontsize=8)
        ax.set_xlabel("s [m]")
    fig.suptitle(title + (f" (t = {t[0]:.4g} s)" if single else f" ({len(t)} records)"), fontsize=10)
    return fig


def gravity_in_view(g, a, b):
    """Gravity seen in a view whose horizontal and vertical axes are the unit vectors a and b: ``(dx, dy, normal)``,
    the in-plane direction (unit, or (0, 0) when gravity is along the line of sight) and the component along a x b
    over ``|g|`` (> 0: out of the view).  None without gravity."""
    g = np.asarray(g, dtype=float)
    gn = float(np.linalg.norm(g))
    if gn == 0.0:
        return None
    v = np.array([g @ a, g @ b]) / gn
    n = float(np.linalg.norm(v))
    normal = float(g @ np.cross(a, b)) / gn
    return (float(v[0] / n), float(v[1] / n), normal) if n > 0.2 else (0.0, 0.0, normal)


def draw_gravity(ax, g, a, b):
    """An arrow labelled "g" in the view's corner along gravity's projection (:func:`gravity_in_view`); gravity along
    the line of sight is written as "g into / out of the view".  Returns the annotation (None without gravity)."""
    v = gravity_in_view(g, a, b)
    if v is None:
        return None
    gn = float(np.linalg.norm(g))
    dx, dy, normal = v
    c = np.array([0.9, 0.84])
    if dx == 0.0 and dy == 0.0:
        return ax.text(c[0], c[1], f"g ({gn:.3g} m/s\u00b2) {'out of' if normal > 0 else 'into'} the view",
                       transform=ax.transAxes, ha="right", va="center", fontsize=8, color="tab:red", gid="gravity")
    d = 0.07 * np.array([dx, dy])
    return ax.annotate(f"g\n{gn:.3g} m/s\u00b2", xy=tuple(c + d), xytext=tuple(c - d), xycoords="axes fraction",
                       textcoords="axes fraction", ha="center", va="center", fontsize=7, color="tab:red", gid="gravity",
                       arrowprops=dict(arrowstyle="-|>", color="tab:red", lw=1.5))


def _rod_figure(run, title):
    from matplotlib import cm, colormaps, colors
    from matplotlib.figure import Figure

    t = run["time"]
    fld = run["fields"]
    r = fld["rod/r"]
    Lam = fld.get("rod/Lambda")
    K, n = len(t), r.shape[1]
    single = K == 1
    scene = _scene(run)
    rod = scene.get("rod", {})
    L = float(scene.get("tube", {}).get("length", 0.0)) or float(np.sum(np.linalg.norm(np.diff(r[0], axis=0), axis=1)))
    rho = float(scene.get("tube", {}).get("radius", 0.02 * L))
    along, w, (o, e, e2, e3) = rod_deflection(r)
    amp = float(np.max(np.linalg.norm(w, axis=-1)))
    mode = rod_view_mode(amp, L)
    planar = rod.get("dimension", 3 if np.ptp(r[..., 2]) > 0 else 2) == 2
    lab = abs(e[0]) > 0.999  # chord ~ +x: its transverse directions are y and z
    an, bn, cn = ("x", "y", "z") if lab else ("along the chord", "across 1", "across 2")

    disp = np.linalg.norm(r - r[0], axis=-1)
    moving = K > 1 and float(np.max(disp)) > ROUNDOFF_FRACTION * L
    probe = int(np.argmax(np.max(disp, axis=0))) if moving else n // 2
    s_of = lambda j: L * j / max(n - 1, 1)  # noqa: E731

    twist = section_twist(Lam) if Lam is not None and K > 1 else None
    spinning = twist is not None and np.max(np.abs(twist)) > 1e-6
    ex, ey, ez = np.eye(3)
    if mode == "deflection":
        f, u = _length_unit(amp)
        X, Y, Z = along + o @ e, f * w[..., 0], f * w[..., 1]
        xl, yl, zl = f"{an} [m]", f"deflection in {bn} [{u}]", f"deflection in {cn} [{u}]"
        head = (f"deflection from the chord through the end nodes, on its own scale "
                f"(largest {amp * f:.3g} {u} = {amp / L:.2g} L)")
        bx, by, bz = e, e2, e3
    else:
        X, Y, Z = r[..., 0], r[..., 1], r[..., 2]
        xl, yl, zl = "x [m]", "y [m]", "z [m]"
        head = "true scale"
        bx, by, bz = ex, ey, ez
        if mode == "rest" and spinning:
            head += (f"; a steady rotation about its own axis: the centreline stays on its chord (largest deflection "
                     f"{amp:.2g} m) and only the sections turn (the mark in the end view, the spin below);\n"
                     "a whirl needs a transverse disturbance (rod.perturbation), modes about this state: varint modes")
        elif mode == "rest":
            head += f"; the centreline stays on its chord (largest deflection {amp:.2g} m)"
    views = [(X, Y, xl, yl, "side view", bx, by)]
    if not planar:
        if mode == "true":  # large motion: three projections of the whole centreline
            views += [(X, Z, xl, zl, "side view", bx, bz), (Y, Z, yl, zl, "end view", by, bz)]
        else:  # the node that moves most (deflection), or its section turning (rest)
            if mode == "deflection":
                views.append((X, Z, xl, zl, "side view", bx, bz))
            views.append((Y, Z, yl, zl, f"end view, node at s = {s_of(probe):.3g} m", by, bz))
            if mode == "deflection" and spinning:  # the whirl seen from the frame turning with the shaft
                c, sn = np.cos(twist[:, probe]), np.sin(twist[:, probe])
                wr = np.stack([c * Y[:, probe] + sn * Z[:, probe], -sn * Y[:, probe] + c * Z[:, probe]], axis=1)
                Yr, Zr = np.zeros_like(Y), np.zeros_like(Z)
                Yr[:, probe], Zr[:, probe] = wr[:, 0], wr[:, 1]
                views.append((Yr, Zr, yl.replace("deflection in", "deflection along the turning"),
                              zl.replace("deflection in", "deflection along the turning"),
                              f"end view, node at s = {s_of(probe):.3g} m, in the frame spinning with the shaft", None, None))

    timeseries = []
    if moving:
        timeseries.append("displacement")
    if spinning:
        timeseries.append("twist")
    gvec = np.asarray(scene.get("environment", {}).get("gravity", (0.0, 0.0, 0.0)), dtype=float)
    if gvec.shape != (3,):
        gvec = np.zeros(3)

    fig = Figure(figsize=(max(4.6 * len(views), 9.0) + 0.8, 4.3 + (3.2 if timeseries else 0.0)), layout="constrained")
    top, bottom = fig.subfigures(2, 1, height_ratios=[4.3, 3.2]) if timeseries else (fig, None)
    widths = [1.0 if v[4].startswith("end view,") else 2.0 for v in views]
    vax = top.subplots(1, len(views), squeeze=False, width_ratios=widths)[0]
    picks = np.unique(np.linspace(0, K - 1, min(K, 8)).astype(int))
    cmap = colormaps["viridis"]
    norm = colors.Normalize(float(t[0]), float(t[-1]) if K > 1 else float(t[0]) + 1.0)
    colour = (lambda k: "k") if single else (lambda k: cmap(norm(t[k])))  # noqa: E731
    for ax, (P, Q, pl, ql, name, va, vb) in zip(vax, views):
        end_view = name.startswith("end view,")
        if va is not None:
            draw_gravity(ax, gvec, va, vb)
        if end_view:
            if mode != "deflection" and va is not None:  # the probe node's section, with a mark along d2 turning with it
                c = np.array([P[0, probe], Q[0, probe]])
                ang = np.linspace(0, 2 * np.pi, 100)
                ax.plot(c[0] + rho * np.cos(ang), c[1] + rho * np.sin(ang), color="0.6", lw=0.8,
                        label=f"section (radius {rho:.3g} m)")
                if Lam is not None:
                    for k in picks:
                        d2 = Lam[k, probe][:, 1]
                        ax.plot([P[k, probe], P[k, probe] + rho * d2[1]], [Q[k, probe], Q[k, probe] + rho * d2[2]],
                                color=colour(k), lw=1.5)
                    ax.plot([], [], color="0.3", lw=1.5, label="mark on the section (d2)")
            if moving:  # the path of the probe node through every record
                ax.plot(P[:, probe], Q[:, probe], color="0.6", lw=0.6, label="path, all records")
            for k in picks:
                ax.plot(P[k, probe], Q[k, probe], "o", color=colour(k), ms=4)
            ax.set_aspect("equal", adjustable="datalim")
            ax.legend(fontsize=7, loc="upper right")
        else:
            if single and mode == "true":  # the unloaded reference: straight along +x from the first node
                ax.plot([X[0, 0], X[0, 0] + L], [Q[0, 0], Q[0, 0]], "--", color="0.6", lw=1, label="straight, unloaded")
            if mode == "deflection":
                ax.axhline(0.0, color="0.6", lw=0.8, ls="--", label="chord")
            for k in picks:
                ax.plot(P[k], Q[k], color=colour(k), lw=1.3, marker="o" if single else None, ms=2.5,
                        label="centreline (nodes)" if single else None)
            if mode != "deflection":
                ax.set_aspect("equal", adjustable="datalim")
            if single or mode == "deflection":
                ax.legend(fontsize=7, loc="best")
        ax.set_xlabel(pl)
        ax.set_ylabel(ql)
        ax.set_title(name, fontsize=9)
        ax.grid(alpha=0.3)
    if not single:
        top.colorbar(cm.ScalarMappable(norm=norm, cmap=cmap), ax=list(vax), label="t [s]", shrink=0.9)
    what = "centreline" if single else f"centreline at {len(picks)} times"
    import textwrap

    width = int(13 * fig.get_figwidth())  # characters of a 9-point line across the figure: wrapped, never cut
    top.suptitle("\n".join(textwrap.fill(line, width) for line in f"{title}\n{what}: {head}".split("\n")), fontsize=9)

    if timeseries:
        tf, tlabel = _time_axis(t)
        tax = bottom.subplots(1, len(timeseries), squeeze=False)[0]
        for ax, kind in zip(tax, timeseries):
            if kind == "displacement":
                d = r[:, probe] - r[0, probe]
                big = float(np.max(np.abs(d)))
                f, u = _length_unit(big)
                for i, c in enumerate("xyz"):
                    if np.max(np.abs(d[:, i])) > 1e-3 * big:
                        ax.plot(t * tf, d[:, i] * f, lw=1, label=c)
                ax.set_ylabel(f"displacement [{u}]")
                ax.set_title(f"node at s = {s_of(probe):.3g} m (largest motion), from t = 0", fontsize=9)
            else:
                for j in sorted({0, n // 2, n - 1}):
                    rate = (twist[-1, j] - twist[0, j]) / (t[-1] - t[0])
                    ax.plot(t * tf, twist[:, j], lw=1, label=f"s = {s_of(j):.3g} m (mean {rate:.3g} rad/s)")
                ax.set_ylabel("angle [rad]")
                ax.set_title("rotation of the sections about their own axis since t = 0", fontsize=9)
            ax.legend(fontsize=7)
            ax.set_xlabel(tlabel)
            ax.grid(alpha=0.3)
    return fig


def _title(run):
    title = str(run["attrs"].get("title", "")) or "varint run"
    if run["attrs"].get("static"):
        spin = run["attrs"].get("steady_rotation")
        title += (f" - steady rotation at {np.round(np.asarray(spin, dtype=float), 6).tolist()} rad/s" if spin is not None
                  else " - static equilibrium")
    return title


def declared_invariants(run):
    """The invariants the run's model declares (``varint check``'s list), derived from the scene stored in the file
    (its model is built, not stepped); None when the file has no readable scene."""
    from .errors import VarintError
    from .model.model import build_model
    from .scene.schema import parse_scene

    text = run["attrs"].get("scene_toml")
    if not text:
        return None
    try:
        return list(build_model(parse_scene(text)).invariants())
    except (VarintError, ValueError, KeyError, TypeError):
        return None


def _geometry(run):
    """{"gravity": g, "axis": (point, unit vector)}: the scene's gravity and a rod's axis through its first record's
    end nodes (the bearing line of a shaft on bearings)."""
    g = _scene(run).get("environment", {}).get("gravity", (0.0, 0.0, 0.0))
    out = {"gravity": np.asarray(g, dtype=float) if np.size(g) == 3 else np.zeros(3)}
    r = run["fields"].get("rod/r")
    if r is not None and len(r):
        e = r[0, -1] - r[0, 0]
        n = float(np.linalg.norm(e))
        if n > 0:
            out["axis"] = (r[0, 0], e / n)
    return out


def monitors_figure(run, invariants=False):
    """matplotlib Figure of a run's monitors (``run`` as :func:`varint.run.io.read_run` returns it), or None.

    ``invariants``: the model's declared invariants (a list), None for every momentum, or False (the default) to
    derive them from the stored scene (:func:`declared_invariants`); the title lists them."""
    if len(run["time"]) == 0 or not run["monitors"]:
        return None
    if invariants is False:
        invariants = declared_invariants(run)
    title = _title(run)
    if invariants is not None:
        title += "\ninvariants the model declares: " + (", ".join(invariants) or "none")
    return _monitors_figure(run["time"], monitor_panels(run["monitors"], invariants, _geometry(run)), title)


def fields_figure(run):
    """matplotlib Figure of a run's fields (rod centreline, or the tube's p, u, R), or None."""
    if len(run["time"]) == 0:
        return None
    if "rod/r" in run["fields"]:
        return _rod_figure(run, _title(run))
    scene = _scene(run)
    maps = _tube_maps(run["fields"], scene)
    return _tube_figure(run["time"], maps, _title(run), scene) if maps else None


# -- profiles at chosen times (varint plot --at) -----------------------------------------------------------

def nearest_records(t, times):
    """Indices of the records nearest to each of ``times`` (in the order asked)."""
    t = np.asarray(t, dtype=float)
    return [int(np.argmin(np.abs(t - float(T)))) for T in times]


class ExactProfiles:
    """The exact solution a scene has, on an unbounded tube: ``fields(s, t)`` -> {"pressure", "density", "velocity"
    (and "R")} along s at time t; ``name`` says which solution it is; ``valid_until`` the time the first wave reaches
    an end of the finite tube (the exact solution knows no ends)."""

    def __init__(self, name, fields, valid_until=math.inf):
        self.name, self.fields, self.valid_until = name, fields, valid_until


def exact_profiles(scene):
    """The :class:`ExactProfiles` of a validated scene (:class:`varint.scene.schema.Scene`), or None.

    A Riemann problem: a straight tube (no [rod]) with a rigid uniform wall (no [wall], no area_table), an ideal gas
    started from two constant states, the scene's fluid state and one ``[[fluid.initial]]`` region (density and
    pressure, optionally velocity) reaching one end, without perturbations: Toro's exact solution
    (:class:`varint.exact.shocks.RiemannSolution`).  The paper's traveling shock (``[initial.traveling_shock]``): its
    profile moved at its speed (:meth:`varint.exact.shocks.TravelingShock.profile`)."""
    from .exact.shocks import RiemannSolution

    f = scene.fluid
    if f is None or scene.rod is not None:
        return None
    L = float(scene.tube.length)
    ts = f.get("traveling_shock")
    if ts is not None:
        wave, x_s = ts.wave, float(ts.position)

        def fields(s, t):
            R, rho, u, p = wave.profile(np.asarray(s, dtype=float) - x_s - wave.speed * t)
            return {"pressure": p, "density": rho, "velocity": u, "R": R}

        return ExactProfiles(f"traveling shock at {wave.speed:.6g} m/s", fields)
    if (scene.wall is not None or scene.tube.area_table is not None or f.model != "ideal-gas" or f.perturbation
            or len(f.initial) != 1 or f.ends.s0 != "closed"):
        return None
    reg = f.initial[0]
    if reg.density is None or reg.pressure is None:
        return None
    base = (float(f.density), float(f.velocity), float(f.pressure))
    other = (float(reg.density), float(f.velocity if reg.velocity is None else reg.velocity), float(reg.pressure))
    a, b = float(reg["from"]), float(reg["to"])
    if b >= L and 0.0 < a < L:
        x0, left, right = a, base, other
    elif a <= 0.0 and 0.0 < b < L:
        x0, left, right = b, other, base
    else:
        return None
    sol = RiemannSolution(left, right, gamma=f.gamma or 1.4)
    SL, SR = sol.shock_speeds()
    slow = SL if SL is not None else left[1] - sol.cl   # the left wave's front (a shock, or a rarefaction's head)
    fast = SR if SR is not None else right[1] + sol.cr
    until = min(x0 / -slow if slow < 0 else math.inf, (L - x0) / fast if fast > 0 else math.inf)

    def fields(s, t):
        s = np.asarray(s, dtype=float)
        if t <= 0:
            rho = np.where(s < x0, left[0], right[0])
            return {"density": rho, "velocity": np.where(s < x0, left[1], right[1]),
                    "pressure": np.where(s < x0, left[2], right[2])}
        rho, u, p = sol.sample(s, t, x0=x0)
        return {"pressure": p, "density": rho, "velocity": u}

    return ExactProfiles(f"Riemann problem, exact (Toro), diaphragm at s = {x0:.4g} m", fields, until)


def profiles_figure(run, times):
    """matplotlib Figure of p, rho, u, R along the tube at the records nearest to ``times`` (each curve says its
    record's time and the time asked), with the scene's exact solution (:func:`exact_profiles`) dashed; or None
    for a run without tube fields.  Returns ``(figure, record indices)``."""
    from matplotlib.figure import Figure

    from .errors import VarintError
    from .scene.schema import parse_scene

    t = run["time"]
    fld = run["fields"]
    raw = _scene(run)
    maps = [m for m in _tube_maps(fld, raw)]
    if not maps or not len(t):
        return None, []
    exact = None
    try:
        exact = exact_profiles(parse_scene(run["attrs"].get("scene_toml", "")))
    except (VarintError, ValueError, TypeError, AttributeError):
        exact = None
    ks = nearest_records(t, times)
    ncol = 2 if len(maps) > 2 else len(maps)
    nrow = math.ceil(len(maps) / ncol)
    fig = Figure(figsize=(6.2 * ncol, 3.6 * nrow + 0.6), layout="constrained")
    axes = fig.subplots(nrow, ncol, squeeze=False)
    for ax in axes.flat[len(maps):]:
        ax.set_visible(False)
    keys = {"pressure": "pressure", "density": "density", "velocity": "velocity", "R": "R"}
    for ax, (name, sym, unit, x, y, key) in zip(axes.flat, maps):
        for i, (T, k) in enumerate(zip(times, ks)):
            xs, ys = x[k], y[k]
            ok = np.isfinite(xs) & np.isfinite(ys)
            ax.plot(xs[ok], ys[ok], "-", color=f"C{i}", lw=1.3, marker="." if np.count_nonzero(ok) <= 60 else None,
                    label=f"t = {t[k]:.4g} s (asked {float(T):.4g} s)")
            if exact is not None:
                sg = np.linspace(np.nanmin(x), np.nanmax(x), 1200)
                ex = exact.fields(sg, float(t[k])).get(keys[key])
                if ex is not None:
                    ax.plot(sg, ex, "--", color="k", lw=0.9, label="exact" if i == 0 else None)
        ax.set_xlabel("s [m]")
        ax.set_ylabel(f"{sym} [{unit}]")
        ax.set_title(name, fontsize=9)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="best")
    head = _title(run) + "\nprofiles at the records nearest to the times asked"
    if exact is not None:
        head += f"; dashed: {exact.name}"
        if math.isfinite(exact.valid_until):
            head += f" (an unbounded tube: valid to t = {exact.valid_until:.4g} s, when a wave reaches an end)"
    fig.suptitle(head, fontsize=9)
    return fig, ks


def plot_profiles(path, times, outdir=None):
    """Write ``<stem>_profiles.png`` (:func:`profiles_figure`); returns ``(path or None, record times drawn)``."""
    run = read_run(path)
    fig, ks = profiles_figure(run, times)
    if fig is None:
        return None, []
    stem = Path(path).stem
    outdir = Path(outdir) if outdir else Path(path).resolve().parent
    outdir.mkdir(parents=True, exist_ok=True)
    out = outdir / f"{stem}_profiles.png"
    fig.savefig(out, dpi=110)
    return out, [float(run["time"][k]) for k in ks]


def plot_run(path, outdir=None):
    """Write ``<stem>_monitors.png`` and ``<stem>_fields.png``; returns their paths."""
    run = read_run(path)
    stem = Path(path).stem
    outdir = Path(outdir) if outdir else Path(path).resolve().parent
    outdir.mkdir(parents=True, exist_ok=True)
    written = []
    for kind, make in (("monitors", monitors_figure), ("fields", fields_figure)):
        fig = make(run)
        if fig is not None:
            p = outdir / f"{stem}_{kind}.png"
            fig.savefig(p, dpi=110)
            written.append(p)
    return written


def centreline_frames(run, triads=True):
    """The data of a rod run's animation: per record the centreline (N+1, 3), the frames' first axes scaled to
    the tube radius (N+1, 3) when ``triads``, and, for the coupled tube, the fluid labels' positions and the
    parcels' pressures.  Returns ``(t, r, axes or None, X or None, p or None)``."""
    fld = run["fields"]
    r = fld["rod/r"]
    scene = _scene(run)
    rho = float(scene.get("tube", {}).get("radius", 0.02))
    axes = None
    if triads and "rod/Lambda" in fld:
        axes = 3.0 * rho * fld["rod/Lambda"][..., :, 0]  # column 0: the section's normal E_1 in space
    X = fld.get("fluid/position")
    p = fld.get("fluid/pressure") if X is not None else None
    return run["time"], r, axes, X, p


def animation_figure(run, max_frames=400):
    """The figure of ``varint plot --animate`` and how to draw it: ``(figure, draw(k), record indices)``, or None for a
    run without a rod.  The rod's centreline in 3D; for the coupled tube the fluid's labels coloured by the pressure
    of their parcels, with the colour bar of that scale; the scene's gravity as an arrow labelled g; the run's whole
    title (wrapped, never cut) and the record's time."""
    import textwrap

    from matplotlib import cm, colormaps, colors
    from matplotlib.figure import Figure

    if "rod/r" not in run["fields"]:
        return None
    t, r, axes, X, p = centreline_frames(run)
    K = len(t)
    pick = np.unique(np.linspace(0, K - 1, min(K, max_frames)).round().astype(int))
    fig = Figure(figsize=(7.4, 6.0))
    ax = fig.add_subplot(projection="3d")
    allpts = r.reshape(-1, 3)
    lo, hi = allpts.min(0), allpts.max(0)
    mid, half = 0.5 * (lo + hi), 0.5 * float(np.max(hi - lo)) or 1.0
    for set_lim, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), mid):
        set_lim(c - 1.05 * half, c + 1.05 * half)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    if float(np.ptp(allpts[:, 2])) <= ROUNDOFF_FRACTION * half:  # planar motion: look at its plane from +z
        ax.view_init(elev=90, azim=-90)
        ax.set_zticks([])
        ax.set_zlabel("")
    g = np.asarray(_scene(run).get("environment", {}).get("gravity", (0.0, 0.0, 0.0)), dtype=float)
    if g.shape == (3,) and np.any(g):  # gravity from a corner of the box, a quarter of its size
        gn = float(np.linalg.norm(g))
        base = mid + 0.8 * half * np.array([-1.0, 1.0, 1.0]) - 0.25 * half * g / gn
        ax.quiver(*base, *(0.5 * half * g / gn), color="tab:red", lw=2, arrow_length_ratio=0.25)
        ax.text(*(base - 0.08 * half * g / gn), f"g ({gn:.3g} m/s\u00b2)", color="tab:red", fontsize=8, gid="gravity")
    (line,) = ax.plot([], [], [], color="0.2", lw=2)
    quiv = []
    scat = None
    norm = None
    cmap = colormaps["viridis"]
    if X is not None and p is not None:
        finite = p[np.isfinite(p)]
        if finite.size:
            lo_p, hi_p = float(finite.min()), float(finite.max())
            norm = colors.Normalize(lo_p, hi_p if hi_p > lo_p else lo_p + 1.0)
            fig.colorbar(cm.ScalarMappable(norm=norm, cmap=cmap), ax=ax, shrink=0.6, pad=0.1,
                         label="p [Pa] (each label: the parcel it begins)")
    head = textwrap.fill(_title(run), width=80)
    title = ax.set_title("", fontsize=8)

    def draw(k):
        nonlocal scat
        line.set_data_3d(r[k, :, 0], r[k, :, 1], r[k, :, 2])
        for q in quiv:
            q.remove()
        quiv.clear()
        if axes is not None:
            quiv.append(ax.quiver(r[k, :, 0], r[k, :, 1], r[k, :, 2], axes[k, :, 0], axes[k, :, 1], axes[k, :, 2],
                                  color="tab:orange", lw=0.6, arrow_length_ratio=0.0))
        if X is not None:
            # each label coloured by the pressure of the parcel it begins (the last one by its left neighbour's)
            pk = np.append(p[k], p[k][-1]) if p is not None else None
            if scat is not None:
                scat.remove()
            scat = ax.scatter(X[k, :, 0], X[k, :, 1], X[k, :, 2], s=8,
                              c=cmap(norm(pk)) if norm is not None else "tab:blue", depthshade=False)
        title.set_text(f"{head}\nt = {t[k]:.4g} s")
        return [line]

    return fig, draw, pick


def animate_run(path, outdir=None, fps=20, max_frames=400):
    """Write ``<stem>_anim.gif`` (:func:`animation_figure`) with matplotlib's Pillow writer.  Returns its path, or None
    for a run without a rod."""
    from matplotlib import animation

    made = animation_figure(read_run(path), max_frames)
    if made is None:
        return None
    fig, draw, pick = made
    anim = animation.FuncAnimation(fig, draw, frames=pick, blit=False)
    stem = Path(path).stem
    outdir = Path(outdir) if outdir else Path(path).resolve().parent
    outdir.mkdir(parents=True, exist_ok=True)
    out = outdir / f"{stem}_anim.gif"
    anim.save(out, writer=animation.PillowWriter(fps=fps), dpi=80)
    return out
