"""The energy-momentum scheme: a discrete-gradient step that keeps the energy to the solver tolerance and the momenta
to round-off at steps set by the motion (docs/theory.md §12a-§12c), for the rod alone
(:class:`varint.schemes.em_rod.RodEMStep`) and the coupled tube (:class:`varint.schemes.em_tube.TubeEMStep`).

Its unknowns are its own (positions, director matrices, the labels' reference coordinates and positions, multipliers:
:meth:`EnergyMomentum.unknowns`); the state it exchanges with the driver is the model's (:mod:`varint.model.model`),
with its own variables carried in ``State.data`` so that a run resumes.  Its monitors are its own conserved energy and
momenta.
"""

from __future__ import annotations

from types import SimpleNamespace

from . import em_rod, em_tube
from .base import Scheme, Stepper, StepReport
from .midpoint import make_scheme
from .monitors import LevelMonitors
from .state import State
from .variational import VariationalStepper
from ..terms.shock_capturing import ShockCapturing, make_shock_capturing
from ..terms.open_ends import OpenMeanValuePressure

__all__ = ["EnergyMomentum", "EnergyMomentumStepper"]


class EnergyMomentum(Scheme):
    """Discrete gradients of the potential with the kinetic energy in the director velocities (docs/theory.md §12a)."""

    name = "energy-momentum"
    order = 2
    summary = ("discrete-gradient step: energy kept to the solver tolerance, momenta to round-off, at steps set by the "
               "motion")

    def supports(self, model):
        return em_rod.supports(model)

    def stepper(self, model, h, tol=None, max_iter=None, state=None):
        if model.rod is None:
            return straight_tube_stepper(model, h, tol, max_iter, state)
        return EnergyMomentumStepper(model, h, tol, max_iter, state)

    def unknowns(self, model):
        """The step's unknowns per block (``(counts, inertial, algebraic)``); supports keep their rows as trivial
        equations, so every node counts.  The straight tube's are the midpoint's (None)."""
        rod, t = model.rod, model.tube
        if rod is None:
            return None
        n1 = rod.N + 1
        inertial = {"r": 3 * n1, "directors": 9 * n1}
        algebraic = {"orthonormality": 6 * n1}
        if rod.constrained:
            algebraic["n"] = 3 * rod.N  # the element forces that hold Gamma = chi
        if model.coupled:
            if t.has_wall:  # a quasistatic wall's radii are unknowns without inertia (theory §12b)
                (inertial if t.wall_dynamic else algebraic)["R"] = n1
            inertial["s"] = t.M - 1  # interior labels: the reference coordinate (no inertia of its own) and the position
            inertial["X"] = 3 * (t.M - 1)
            algebraic["label_constraint"] = 3 * (t.M - 1)
            if t.incompressible:
                algebraic["mu"] = t.M
        return {**inertial, **algebraic}, sum(inertial.values()), sum(algebraic.values())


def straight_tube_stepper(model, h, tol=None, max_iter=None, state=None):
    """The straight tube's energy-momentum step (docs/theory.md §12d): the midpoint step of its labels and radii
    with the parcels' pressures and volumes replaced by their discrete gradients -- the mean-value pressure of an
    ideal gas or a barotropic liquid and the averaged-vector-field gradient of a swelling parcel's volume, §11a's force
    with no viscosity (a scene's own [shock_capturing] force already carries them); with open ends in a rigid uniform
    duct, the mean-value pressures on the lattice of each level (varint.terms.open_ends.OpenMeanValuePressure)."""
    t = model.tube
    extra = []
    if getattr(t, "open", False):  # open ends: the rigid uniform duct's pressures on the lattice of the level (§13.4)
        extra.append(OpenMeanValuePressure(t))
    elif not any(isinstance(f, ShockCapturing) for f in model.forces):
        extra.append(make_shock_capturing(t, SimpleNamespace(quadratic=0.0, linear=0.0, limiter="none")))
    tcfg = model.scene.time
    return VariationalStepper(model, h, "midpoint", min(tcfg.newton_tol, 1e-12) if tol is None else tol, max_iter,
                              state, extra_forces=extra, scheme_name="energy-momentum")


class EnergyMomentumStepper(LevelMonitors, Stepper):
    """The energy-momentum step of one model: its engine (:class:`~varint.schemes.em_rod.RodEMStep` or
    :class:`~varint.schemes.em_tube.TubeEMStep`) steps its own variables; the model's state follows each step."""

    def __init__(self, model, h, tol=None, max_iter=None, state=None):
        tcfg = model.scene.time
        self.model = model
        self.h = float(h)
        if model.coupled:
            self.engine = em_tube.TubeEMStep(model, self.h, tol=min(tcfg.newton_tol, 1e-12) if tol is None else tol)
        else:
            self.engine = em_rod.RodEMStep(model, self.h, tol=min(tcfg.newton_tol, 1e-13) if tol is None else tol)
        #: the midpoint's discrete action: it lays out the model's state, which the fields and mass monitors read
        self.action = make_scheme(model, self.h, "midpoint")
        if state is None and model.initial_data:
            model.set_state_data(model.initial_data)
        self.state = state if state is not None else State(0, 0.0, *model.initial_state(self.h), data=model.state_data())

    @property
    def state(self):
        return self._state

    @state.setter
    def state(self, st):
        self.adopt(st)

    @property
    def open(self):
        return False  # (open ends are not covered: EnergyMomentum.supports)

    def step(self, state):
        if state is not self._state:
            self.state = state
        new = self.engine.step_state(self._state, self.model)
        if new.data is not None:  # data a step changes in the model (the parcels' heated entropy) is the new level's
            new.data.update(self.model.state_data() or {})
        # the state's predictor data (State.v) from the step's two levels: the fields' velocities are the step's
        new.v = self.action.velocity(new.q_prev, new.q)
        self.state = new
        last = self.engine.last
        # fallback 1: full Newton restarted; 2: solved from two half steps
        return self._state, StepReport(last["iterations"], 0, last["jacobians"], last["fallback"] > 0,
                                       halved=last["fallback"] == 2)

    def monitors(self):
        """The engine's own conserved energy and momenta; the rod alone's also the model's level monitors (mass, frames,
        the constraint's residual), which the engine's replace where both give one."""
        if self.model.coupled:
            return self.engine.monitors()
        out = self._rod_monitors()
        out.update(self.engine.monitors())
        return out

    def invalidate(self):
        self.engine._lu = None
