"""Stability thresholds of a scene: the value of one scene key where the largest growth rate of its modes crosses
zero (docs/validation.md, "Modes of a flowing tube")."""

from __future__ import annotations

import tomllib

from ..errors import SolverError
from ..scene.schema import parse_scene
from ..scene.text import resolve_key, set_key, to_toml
from .modes import scene_modes, strongest

__all__ = ["threshold"]


def threshold(text, lo, hi, key="fluid.velocity", count=20, about="initial", rtol=1e-6, max_iter=60):
    """The value of the scene key ``key`` in [lo, hi] where the largest growth rate of the flowing tube's modes
    crosses zero (stable at ``lo``, unstable at ``hi``), by bisection on the sign of that growth rate.

    ``text``: the scene's TOML text (the key is set in it per point as ``varint sweep --vary`` does, and the point
    revalidated).
    Returns ``{"value", "lo", "hi", "frequency", "evaluations"}``: the bracket after convergence to ``rtol`` of
    ``hi``, and the frequency of the growing mode at ``hi`` (0 for divergence).  A bracket with no sign change is
    a one-line error.
    """
    def at(v):
        return strongest(scene_modes(_with_key(text, key, v), count=count, about=about, source=key)["modes"])

    a, b = at(lo), at(hi)
    if a["growth_rate"] > 0.0 or not b["growth_rate"] > 0.0:
        raise SolverError(f"threshold: {key} in [{lo:g}, {hi:g}] does not bracket a loss of stability (largest growth "
                          f"rate {a['growth_rate']:.3g} at {lo:g}, {b['growth_rate']:.3g} at {hi:g})")
    n = 2
    while hi - lo > rtol * abs(hi) and n < max_iter:
        mid = 0.5 * (lo + hi)
        c = at(mid)
        n += 1
        if c["growth_rate"] > 0.0:
            hi, b = mid, c
        else:
            lo = mid
    return {"value": 0.5 * (lo + hi), "lo": lo, "hi": hi, "frequency": b["frequency"], "evaluations": n}


def _with_key(text, key, value):
    """The validated scene of ``text`` with one dotted key set (:func:`varint.scene.text.resolve_key` and ``set_key``, as ``varint sweep`` does)."""
    path, decl = resolve_key(key)
    doc = set_key(tomllib.loads(text), path, int(value) if decl.kind == "int" else float(value))
    return parse_scene(to_toml(doc))
