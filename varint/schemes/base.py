"""The scheme protocol: what every time-stepping scheme declares and provides (docs/architecture.md, "Schemes").

A :class:`Scheme` is a registered object (:mod:`varint.schemes.registry`) that declares

* ``name`` — the value of the scene key ``time.scheme``;
* ``order`` — its global order in h (asserted by tests/test_convergence.py and tests/test_capabilities.py);
* ``summary`` — one line for ``varint check`` and docs/capabilities.md;
* :meth:`Scheme.supports` — None when it can step a model, else the reason in one line, naming the scene key that
  decides it.  The driver's refusal, ``varint check``'s listing and the capability table are generated from it and
  from nowhere else;

and builds a :class:`Stepper` for one model and step size.  A stepper takes a state (:class:`State`) and returns the
next state and the statistics of that step (a :class:`StepReport`), as the steps of scipy's ``OdeSolver`` and
diffrax's solvers do; the driver (:class:`varint.run.simulation.Simulation`) owns the time loop, output and the run's
statistics record.  A stepper also reports the monitors and fields of its current level: the energy a scheme
conserves is its own (the discrete action's for the variational schemes, the discrete-gradient energy for the
energy-momentum scheme).
"""

from __future__ import annotations

from dataclasses import dataclass

from .state import State

__all__ = ["Scheme", "Stepper", "StepReport", "State", "MAX_HALVINGS"]


@dataclass
class StepReport:
    """The statistics of one step: Newton iterations, residual and Jacobian evaluations, and the fallbacks it
    needed (a damped Newton restart, or two half steps: counted once per step)."""

    iterations: int = 0
    n_residual: int = 0
    n_jacobian: int = 0
    fallback: bool = False
    #: the step at h failed (Newton, a chart limit, a folded lattice) and was taken as shorter steps
    halved: bool = False


#: how often a step may be halved when it fails at its own size (h/2, h/4, h/8; docs/theory.md §12c, §4b)
MAX_HALVINGS = 3


class Scheme:
    """A registered time-stepping scheme (see the module notes)."""

    name = ""
    order = 2
    summary = ""

    def supports(self, model):
        """None when this scheme steps ``model``, else one line: the scene key and why not."""
        raise NotImplementedError

    def stepper(self, model, h, tol=None, max_iter=None, state=None):
        """The :class:`Stepper` of ``model`` with step ``h``, started from ``state`` (default: the model's initial
        state).  Call only when :meth:`supports` is None."""
        raise NotImplementedError

    def unknowns(self, model):
        """The unknowns this scheme solves for per block ``(counts, inertial, algebraic)`` for ``varint check``,
        or None when they are the model's own step unknowns (:mod:`varint.model.model`)."""
        return None


class Stepper:
    """One model stepped by one scheme.  ``state`` is the current level; :meth:`step` advances it."""

    #: the model and the step size
    model = None
    h = 0.0

    def step(self, state):
        """``(next state, StepReport)`` from ``state`` (normally the current level)."""
        raise NotImplementedError

    def adopt(self, st):
        """Make ``st`` the current level: a checkpoint written before the rod's floating origin existed gains it
        (:meth:`varint.model.model.Model.upgrade_level`), and the model takes the level's evolving data."""
        st.q = self.model.upgrade_level(st.q)
        if st.q_prev is not None:
            st.q_prev = self.model.upgrade_level(st.q_prev)
        if st.data:
            self.model.set_state_data(st.data)
        self._state = st

    def monitors(self):
        """Invariants and energies of the current level (a dict of floats and arrays)."""
        raise NotImplementedError

    def fields(self):
        """Field values at the current level, keyed by their HDF5 path under /fields."""
        raise NotImplementedError

    def invalidate(self):
        """Forget reused factorisations (done at checkpoints so that a restart repeats the same arithmetic)."""
