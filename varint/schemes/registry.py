"""The registered schemes: every value of ``time.scheme`` is a :class:`varint.schemes.base.Scheme` here, and what a
scheme can step is asked of it (``supports``) and of nothing else: the driver's refusal, ``varint check``'s listing
and docs/capabilities.md are generated from it."""

from __future__ import annotations

from ..errors import SceneError
from .base import Scheme
from .energy_momentum import EnergyMomentum
from .variational import Midpoint, Trapezoidal

__all__ = ["SCHEMES", "scheme_named", "supports", "refusals", "check_supported"]

#: name -> scheme, in the order ``varint check`` lists them
SCHEMES: dict[str, Scheme] = {s.name: s for s in (Midpoint(), Trapezoidal(), EnergyMomentum())}


def scheme_named(name):
    """The registered scheme called ``name`` (a one-line SceneError naming the choices otherwise)."""
    try:
        return SCHEMES[name]
    except KeyError:
        raise SceneError(f"time.scheme: unknown scheme {name!r}; one of {', '.join(map(repr, SCHEMES))}") from None


def supports(name, model):
    """None when scheme ``name`` steps ``model``, else its reason (one line)."""
    return scheme_named(name).supports(model)


def refusals(model):
    """{scheme name: None (it runs the model) or the reason it does not}, for every registered scheme."""
    return {name: s.supports(model) for name, s in SCHEMES.items()}


def check_supported(model, name=None):
    """The scheme ``name`` (default: the scene's ``time.scheme``) if it steps ``model``; else a :class:`SceneError`
    with its reason, and the schemes that do run the model."""
    name = name or model.scene.time.scheme
    sch = scheme_named(name)
    reason = sch.supports(model)
    if reason is not None:
        others = [n for n, why in refusals(model).items() if why is None and n != name]
        hint = f" (this scene runs with {', '.join(map(repr, others))})" if others else ""
        raise SceneError(reason + hint, source=model.scene.path)
    return sch
