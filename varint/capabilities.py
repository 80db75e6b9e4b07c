"""What runs: every registered scheme against every kind of scene, from the schemes' own ``supports``.

The grid is the model (the rod alone, the straight tube, the coupled tube) x its ends (closed, periodic, open) x the
wall (rigid, dynamic, quasistatic) x the fluid (gas, barotropic liquid, incompressible liquid) x the options
(``[shock_capturing]``, ``rod.constraint``).  Each cell is one small scene (:func:`grid_scene`): either the scene
itself is refused by the scene validator (a combination that has no meaning, e.g. shock capturing without a gas),
or each scheme runs it or refuses it with the reason its ``supports`` gives.  docs/capabilities.md is this module's
output (``python3 -m varint.capabilities > docs/capabilities.md``); tests/test_capabilities.py checks that the page is
current and steps every cell that a scheme runs, checking the invariants its model declares.
"""

from __future__ import annotations

import itertools
import sys
from dataclasses import dataclass

from .errors import VarintError
from .model.model import build_model
from .scene.schema import parse_scene
from .scene.standard import AIR, RUBBER_WALL
from .scene.text import to_toml
from .schemes.registry import SCHEMES, refusals

__all__ = ["Cell", "GRID", "grid_scene", "cells", "markdown"]

MODELS = ("rod", "tube", "coupled")
ENDS = ("closed", "periodic", "open")
WALLS = ("rigid", "dynamic", "quasistatic")
FLUIDS = ("gas", "barotropic", "liquid")

#: a rod section of order one (N, m, kg) and a liquid of water's density: the cells run a few steps of each kind of
#: scene, not its hardest physics (water's own bulk modulus in a closed inextensible hose is a case of the hard-case
#: corpus, not of this table), so the barotropic liquid is 100x more compressible than water (c = 148 m/s)
SECTION = dict(mass_per_length=1.0, rotary_inertia=0.01, bending_stiffness=1.0, torsional_stiffness=0.8,
               axial_stiffness=100.0, shear_stiffness=60.0)
WATER = {"density": 1000.0, "pressure": 101325.0}
BULK_MODULUS = 2.2e7
#: the time step of the cells, below the sound crossing time of a parcel (1/16 m at 340 m/s, 148 m/s); the
#: trapezoidal rule is explicit, and its energy oscillates by O((h omega)^2) of the motion's: its cells step at a fifth
STEP = 1e-4
TRAPEZOIDAL_STEP = 2e-5


@dataclass(frozen=True)
class Cell:
    """One combination of the grid (``option``: "", "shock_capturing" or "constraint")."""

    model: str
    ends: str = "closed"
    wall: str = ""
    fluid: str = ""
    option: str = ""

    @property
    def label(self):
        parts = [self.model, self.ends] if self.model != "rod" else ["rod", self.ends]
        if self.model != "rod":
            parts += [self.wall, self.fluid]
        if self.option:
            parts.append(self.option)
        return "-".join(parts)


def _grid():
    out = []
    for ends, option in itertools.product(("closed", "periodic"), ("", "constraint")):
        out.append(Cell("rod", ends, option=option))
    for model in ("tube", "coupled"):
        options = ("", "shock_capturing") + (("constraint",) if model == "coupled" else ())
        for ends, wall, fluid, option in itertools.product(ENDS, WALLS, FLUIDS, options):
            out.append(Cell(model, ends, wall, fluid, option))
    return tuple(out)


#: every cell, in the order of the table
GRID = _grid()


def grid_scene(cell, scheme="midpoint"):
    """The scene dict of one cell, stepped by ``scheme``: 8 elements, a small perturbation so that things move."""
    h = TRAPEZOIDAL_STEP if scheme == "trapezoidal" else STEP
    d = {"title": f"capability cell {cell.label}", "tube": {"length": 1.0, "nodes": 9, "radius": 0.05},
         "time": {"step": h, "end": 10 * h, "scheme": scheme}}
    if cell.model in ("rod", "coupled"):
        if cell.ends == "periodic":
            rod_ends, initial = {"s0": "periodic", "sL": "periodic"}, {"velocity": [0.0, 0.1, 0.0]}
        else:
            rod_ends, initial = {"s0": "clamped", "sL": "free"}, {}
        rod = dict(SECTION, dimension=3, ends=rod_ends)
        rod["perturbation"] = [{"field": "velocity", "shape": "cosine", "amplitude": 0.05, "wavelength": 2.0}]
        if initial:
            rod["initial"] = initial
        if cell.option == "constraint":
            rod["constraint"] = "inextensible_unshearable"
        d["rod"] = rod
    if cell.model in ("tube", "coupled"):
        fluid = {"gas": dict(AIR), "barotropic": dict(WATER, model="barotropic", bulk_modulus=BULK_MODULUS),
                 "liquid": dict(WATER, model="incompressible")}[cell.fluid]
        fluid["parcels"] = 16
        if cell.ends == "open":
            fluid["ends"] = {"s0": "inflow", "sL": "outflow"}
            fluid["velocity"] = 1.0
        else:
            fluid["ends"] = {"s0": cell.ends, "sL": cell.ends}
            if cell.ends == "periodic":
                fluid["velocity"] = 1.0  # a mean flow: the axial momentum that a periodic tube keeps is not zero
            fluid["perturbation"] = [{"field": "velocity", "shape": "cosine", "amplitude": 0.1, "wavelength": 1.0}]
        d["fluid"] = fluid
        d["environment"] = {"external_pressure": 101325.0}
        if cell.wall != "rigid":
            d["wall"] = dict(RUBBER_WALL, model=cell.wall)
        if cell.option == "shock_capturing":
            d["shock_capturing"] = {}
    return d


def model_of(cell, scheme="midpoint"):
    """``(model, None)`` for a cell, or ``(None, the scene's refusal)`` when the scene validator refuses it."""
    try:
        return build_model(parse_scene(to_toml(grid_scene(cell, scheme)))), None
    except VarintError as exc:
        return None, str(exc).splitlines()[0]


def cells():
    """``[(cell, {scheme: None (runs) or reason})]``, the scene's own refusal under the key "scene" when it has one."""
    out = []
    for cell in GRID:
        model, why = model_of(cell)
        out.append((cell, {"scene": why} if model is None else refusals(model)))
    return out


def markdown(rows=None):
    """docs/capabilities.md: the table, its reasons as numbered notes."""
    rows = cells() if rows is None else rows
    notes = {}

    def note(reason):
        return notes.setdefault(reason, len(notes) + 1)

    names = list(SCHEMES)
    lines = ["# What runs: every scheme on every kind of scene", "",
             "Generated by `python3 -m varint.capabilities > docs/capabilities.md` from the schemes' own `supports` "
             "(varint/schemes/); `tests/test_capabilities.py` fails when this page is not current, and steps every "
             "cell marked *runs* for a few steps, checking the invariants its model declares. Each cell is a small "
             "scene (`varint.capabilities.grid_scene`): 8 elements, 16 parcels, a small perturbation. A number is a "
             "refusal; its reason, one line naming the scene key, is below the table.", "",
             "Schemes: " + "; ".join(f"**{n}** (order {s.order}): {s.summary}" for n, s in SCHEMES.items()) + ".", "",
             "| model | ends | wall | fluid | option | " + " | ".join(names) + " |",
             "|---|---|---|---|---|" + "---|" * len(names)]
    for cell, res in rows:
        if "scene" in res:
            row = [f"scene [{note(res['scene'])}]"] * len(names)
        else:
            row = ["runs" if res[n] is None else f"[{note(res[n])}]" for n in names]
        lines.append(f"| {cell.model} | {cell.ends} | {cell.wall or '-'} | {cell.fluid or '-'} | {cell.option or '-'} | "
                     + " | ".join(row) + " |")
    lines += ["", "Reasons (*scene*: the scene validator refuses the combination for every scheme):", ""]
    lines += [f"{k}. {reason}" for reason, k in notes.items()]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.stdout.write(markdown())
