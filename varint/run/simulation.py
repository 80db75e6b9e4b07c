"""The driver: :class:`Simulation` steps a model in time with its scheme and keeps the run's statistics.

The scheme is the registered one the scene names (``time.scheme``, :mod:`varint.schemes.registry`); a scheme that
cannot step the model is refused here, in one line, with the reason its ``supports`` gives.  The step itself, the
state's layout and the monitors and fields of a level are the scheme's stepper's (:mod:`varint.schemes.base`).
"""

from __future__ import annotations

import logging

from ..schemes.registry import check_supported
from ..schemes.state import StepStats

__all__ = ["Simulation"]

log = logging.getLogger(__name__)


class Simulation:
    """Public step API: ``sim.step()`` advances one time step; ``sim.state`` is the current level.

    ``sim.scheme`` is the registered scheme, ``sim.stepper`` its stepper of this model, ``sim.stats`` the run's
    statistics (the last step's iterations and evaluations, totals, steps that needed a fallback).

    Parameters
    ----------
    model : varint.model.model.Model
    h : float, optional
        Time step (default: the scene's ``time.step``).
    scheme : str, optional
        A registered scheme's name (default: the scene's ``time.scheme``).
    tol, max_iter : optional
        Newton's tolerance and iteration limit (default: the scene's).
    state : optional
        A level (a ``varint.State``) to start from instead of the model's initial state.
    """

    def __init__(self, model, h=None, scheme=None, tol=None, max_iter=None, state=None):
        self.model = model
        self.h = float(h if h is not None else model.scene.time.step)
        self.scheme = check_supported(model, scheme)
        self.stepper = self.scheme.stepper(model, self.h, tol, max_iter, state)
        self.stats = StepStats()

    @property
    def state(self):
        """The current level (a ``varint.State``)."""
        return self.stepper.state

    @state.setter
    def state(self, st):
        self.stepper.state = st

    def step(self):
        """Advance one step; returns the new state."""
        new, report = self.stepper.step(self.stepper.state)
        self.stats.record(report)
        return new

    def monitors(self):
        """Invariants, energies and the last step's Newton iterations at the current level."""
        out = self.stepper.monitors()
        out["newton_iterations"] = self.stats.iterations
        out["halved_steps"] = self.stats.halved_steps
        return out

    def fields(self):
        """Field values at the current level, keyed by their HDF5 path under /fields."""
        return self.stepper.fields()

    def invalidate_jacobian(self):
        """Forget reused factorisations (done at checkpoints so a restart repeats the same arithmetic)."""
        self.stepper.invalidate()
