"""The registered schemes: every value of ``time.scheme`` is a :class:`varint.schemes.base.Scheme` here, and what a
scheme can step is asked of it (``supports``) and of nothing else: the driver's refusal, ``varint check``'s listing
and docs/capabilities.md are generated from it."""

from __future__ import annotations

from ..errors import SceneError
from .base import Scheme
from .energy_momentum import EnergyMomentum
from .variational import Midpoint, Trapezoidal

__all__ = ["SCHEMES", "AUTO", "scheme_named", "supports", "refusals", "check_supported", "resolve"]

#: name -> scheme, in the order ``varint check`` lists them
SCHEMES: dict[str, Scheme] = {s.name: s for s in (Midpoint(), Trapezoidal(), EnergyMomentum())}

#: ``time.scheme = "auto"``: the energy-momentum scheme where it covers the scene (energy to the solver's tolerance at
#: any step: the long coupled runs the midpoint loses, docs/validation.md "Long runs"), else the midpoint
AUTO = "auto"


def resolve(model, name=None):
    """The registered scheme's name that ``name`` (default: the scene's ``time.scheme``) stands for: itself, or for
    ``"auto"`` the energy-momentum scheme where its ``supports`` covers ``model``, else the midpoint."""
    name = name or model.scene.time.scheme
    if name != AUTO:
        return name
    return "energy-momentum" if SCHEMES["energy-momentum"].supports(model) is None else "midpoint"


def scheme_named(name):
    """The registered scheme called ``name`` (a one-line SceneError naming the choices otherwise)."""
    try:
        return SCHEMES[name]
    except KeyError:
        raise SceneError(f"time.scheme: unknown scheme {name!r}; one of {', '.join(map(repr, SCHEMES))} or "
                         f"{AUTO!r}") from None


def supports(name, model):
    """None when scheme ``name`` steps ``model``, else its reason (one line)."""
    return scheme_named(name).supports(model)


def refusals(model):
    """{scheme name: None (it runs the model) or the reason it does not}, for every registered scheme."""
    return {name: s.supports(model) for name, s in SCHEMES.items()}


def check_supported(model, name=None):
    """The scheme ``name`` (default: the scene's ``time.scheme``; ``"auto"`` resolved by :func:`resolve`) if it steps
    ``model``; else a :class:`SceneError` with its reason, and the schemes that do run the model."""
    name = resolve(model, name)
    sch = scheme_named(name)
    model.scheme = name  # (what the model reports, varint info: the scheme that steps it, "auto" resolved)
    reason = sch.supports(model)
    if reason is not None:
        others = [n for n, why in refusals(model).items() if why is None and n != name]
        hint = f" (this scene runs with {', '.join(map(repr, others))})" if others else ""
        raise SceneError(reason + hint, source=model.scene.path)
    return sch
