"""The variational schemes: the discrete Euler-Lagrange equations of the model's L_d (:class:`varint.schemes.midpoint.Step`)
solved by Newton each step, with the potential at the step's midpoint ("midpoint") or averaged over its levels
("trapezoidal", Stormer-Verlet); docs/theory.md §4, §9, §10.

:class:`VariationalStepper` is the step of both.  It solves with :func:`varint.schemes.newton.newton` (chord
iterations on a reused factorisation, a damped full Newton as the fallback), or, for the rod alone, with the compiled
backend :class:`varint.schemes.rod_compiled.FastRodStep` (the same equations in one numba call, docs/theory.md §9 "The
fast rod step").  Open ends move the lattice between steps (:class:`varint.schemes.open_ends.OpenEndsStepping`).
"""

from __future__ import annotations

import numpy as np

from ..errors import SolverError
from ..terms.open_ends import open_end_limits
from ..terms.rod import POLISH_ROD, RATE_REFRESH_ROD, XI_MAX
from . import rod_compiled
from .base import MAX_HALVINGS, Scheme, Stepper, StepReport
from .limits import chart_limit_error, with_scheme_hint
from .midpoint import make_scheme
from .monitors import LevelMonitors
from .newton import RATE_REFRESH, newton, newton_damped
from .open_ends import OpenEndsStepping
from .state import State

__all__ = ["Midpoint", "Trapezoidal", "VariationalStepper"]


class Midpoint(Scheme):
    """The Lie-group midpoint rule: the potential at the step's midpoint (implicit, symmetric, second order)."""

    name = "midpoint"
    order = 2
    summary = "potential at the step's midpoint: implicit, symmetric, second order, A-stable on linear problems"

    def supports(self, model):
        return open_end_limits(model)

    def stepper(self, model, h, tol=None, max_iter=None, state=None):
        return VariationalStepper(model, h, self.name, tol, max_iter, state)


class Trapezoidal(Scheme):
    """Stormer-Verlet on the straight tube: the potential averaged over the step's two levels (explicit)."""

    name = "trapezoidal"
    order = 2
    summary = "potential averaged over the two levels (Stormer-Verlet): explicit, step limited by the fastest mode"

    def supports(self, model):
        if model.rod is not None:
            return ("time.scheme: 'trapezoidal' steps the straight tube only; the rod is integrated by the midpoint "
                    "Lie-group scheme or 'energy-momentum'")
        t = model.tube
        if t.nlam:
            return ("time.scheme: 'trapezoidal' needs every unknown to carry inertia; an incompressible fluid or a "
                    "quasistatic wall has algebraic unknowns (use 'midpoint')")
        if t.open_ends:
            return "time.scheme: open ends need 'midpoint' (the piston's position is taken at the step's midpoint)"
        if model.scene.shock_capturing is not None:
            return "time.scheme: [shock_capturing] needs 'midpoint' (its viscous pressure is implicit)"
        return None

    def stepper(self, model, h, tol=None, max_iter=None, state=None):
        return VariationalStepper(model, h, self.name, tol, max_iter, state)


class VariationalStepper(OpenEndsStepping, LevelMonitors, Stepper):
    """The midpoint or trapezoidal step of one model (see the module notes); ``action`` is its discrete action."""

    def __init__(self, model, h, name="midpoint", tol=None, max_iter=None, state=None, extra_forces=(), depth=0,
                 scheme_name=None):
        tcfg = model.scene.time
        #: the registered scheme this stepper serves (the straight tube's energy-momentum scheme is this step with its
        #: discrete-gradient forces): a failure names another scheme only when it is not already that one
        self.scheme_name = scheme_name or name
        #: step control (docs/theory.md §4b): a step that fails at h is taken as two steps of h/2 (each halved again,
        #: down to h/2**MAX_HALVINGS), then the run returns to h; ``time.adaptive = false`` forbids it
        self.adaptive = bool(tcfg.adaptive)
        self.depth = depth
        self._half = None  # the stepper of h/2 (built when first needed)
        self._last = self  # the stepper that took the last step (its discrete action evaluates that step's energy)
        self.model = model
        self.h = float(h)
        t = model.tube
        if t is not None and t.open_ends and t.inflow == "velocity" and t.U_in * self.h > 0.5 * t.ell_in:
            raise SolverError(f"time.step: the inflow moves {t.U_in * self.h:.3g} m per step, more than half an inflow "
                              f"parcel ({0.5 * t.ell_in:.3g} m); reduce time.step or fluid.parcels")
        self._built_version = None  # open ends: the lattice version the step was built for
        #: the discrete action of one step: L_d, its derivatives, the Newton residual and Jacobian
        #: forces the scheme adds to the model's (the energy-momentum scheme's discrete-gradient pressure)
        self.extra_forces = list(extra_forces)
        self.action = make_scheme(model, self.h, name, self._forces())
        self.tol = tol if tol is not None else tcfg.newton_tol
        self.max_iter = max_iter if max_iter is not None else tcfg.max_iterations
        if state is None and model.initial_data:
            model.set_state_data(model.initial_data)  # a rerun of the model starts from t = 0's data, not a heated run's
        self.state = state if state is not None else State(0, 0.0, *model.initial_state(self.h), data=model.state_data())
        if self.open and state is None:
            self._open_start()
        self._factor = None
        self._fallback = False
        self.scale, self.offset = self._scales()
        # A free rod can travel far from the origin; positions are then kept relative to a floating
        # origin (moved with node 0 each step, exactly, on a binary grid) so that strains and forces
        # are computed from O(L) numbers: with absolute coordinates their round-off grows like eps |r|
        # and a rod drifting 3.7 km lost its angular momentum to 1e-8 (docs/validation.md).
        self.floating_origin = model.rod is not None and model.rod.free
        #: the compiled backend of the rod alone (varint/schemes/rod_compiled.py): the same discrete equations in one
        #: numba call, 4-15x cheaper per step; None where it does not cover the model (its ``supports``)
        self.compiled = None
        if name == "midpoint" and not self.open and rod_compiled.supports(model) is None:
            self.compiled = rod_compiled.FastRodStep(model, self.h, self.tol, self.max_iter)

    def _forces(self):
        """The step's forces: the model's, then the scheme's own (rebuilt with the lattice of open ends)."""
        return list(self.model.forces) + self.extra_forces

    @property
    def state(self):
        """The current level (:class:`varint.schemes.state.State`)."""
        return self._state

    @state.setter
    def state(self, st):
        self.adopt(st)
        if self.open and self.model.tube.lattice_version != self._built_version:
            self._rebuild()

    @property
    def open(self):
        """True for a tube with open ends (docs/theory.md §13)."""
        t = self.model.tube
        return t is not None and getattr(t, "open", False)

    def invalidate(self):
        self._factor = None
        if self.compiled is not None:
            self.compiled.invalidate()

    def _scales(self):
        """Scale of each unknown (Newton's error norm) and the size of the quantity it displaces (the
        round-off reference: the unknowns are displacements from the reference lattice)."""
        m = self.model
        sc = np.ones(m.nz)
        off = np.zeros(m.nz)
        t = m.tube
        if t is not None:
            for name, sl in t.layout.items():
                if name == "s":
                    sc[sl] = t.ell_in if t.open else t.L / t.M
                elif name == "R":
                    sc[sl] = t.R0
                elif name == "mu":
                    # the multiplier is a pressure; its round-off is set by the wall's stiffness (or, in a rigid
                    # tube on a rod, by the rod's axial stiffness per area: the liquid's volume fixes its stretch)
                    w = t.wall
                    if t.open:  # the rigid open tube: the end pressures and the inflow's dynamic pressure
                        sc[sl] = max(abs(m.scene.fluid.pressure), abs(t.p_in), abs(t.p_out), t.rho_in * t.U_in ** 2, 1.0)
                        continue
                    if w is None:
                        EA = m.rod.section.EA
                        p_wall = EA / (np.pi * t.R0 ** 2) if np.isfinite(EA) else 0.0
                    else:
                        p_wall = w.stiffness if w.law == "tube-law" else w.beta2 * t.R0 / (2 * np.pi)
                    sc[sl] = max(abs(m.scene.fluid.pressure), p_wall)
            off[m.tube_z] = np.asarray(abs(t.B).T @ np.abs(t.c0)).ravel()
            if t.open and getattr(t, "level_constraint", False):
                # a liquid held at the levels: its pressures are fixed by the next level's volumes, so their round-off is
                # that of the labels' positions, eps L, times the step's mass over h^2 A: ~20 eps rho ell L / h^2
                # (measured); the scale keeps Newton's tolerance above that floor (1.5e-7 Pa at 400 parcels, h = 2.5e-4)
                mu = t.layout["mu"]
                sl = slice(m.tube_z.start + mu.start, m.tube_z.start + mu.stop)
                sc[sl] = np.maximum(sc[sl], 1e-3 * t.rho0 * t.ell_in * t.L / self.h ** 2)
        if m.rod is not None:
            rs = np.ones((m.N + 1, 6))
            rs[:, :3] = m.ds
            sc[m.rod_z] = rs[m.rod.mask]
            if m.rod.constrained:
                # the multipliers are the elements' internal forces: the bending forces EI/L^2, or the weight
                sec = m.rod.section
                sc[m.rod_lam_z] = max(sec.EI / m.L ** 2, sec.rhoA * m.L * max(float(np.linalg.norm(m.rod.g)), 1.0))
        return sc, off

    def _newton_options(self):
        """Newton's settings follow from the blocks present: frames make chord iterations cheap next to a
        Jacobian and need the momentum residual polished to round-off (varint.terms.rod)."""
        if self.model.has_frames:
            return dict(max_iter=max(self.max_iter, 40), rate_refresh=RATE_REFRESH_ROD, chord_iterations=30,
                        polish=POLISH_ROD, damped_fallback=True)
        # open ends: polish too (an incompressible liquid's pressure is the labels' momentum change over h^2 A: an
        # update left at the tolerance would show in it as noise that the releases at the inlet accumulate)
        return dict(max_iter=self.max_iter, rate_refresh=RATE_REFRESH, chord_iterations=5, polish=2 if self.open else 0,
                    damped_fallback=False)

    def _where(self, n):
        return f"step {n} (t = {n * self.h:.6g} s)"

    def _folded(self, n, problem, what):
        k, text = problem
        t = self.model.tube
        if t.eos is not None and not any(f.declaration.name == "shock_capturing" for f in self.model.forces):
            # a compressible fluid whose labels cross: a compression steepened until the lattice folds, i.e. a shock
            # forming; no step size resolves it (the exact solution has a discontinuity), the viscosity does (§11a)
            return SolverError(f"{self._where(n)}: {text} {what}: a shock is forming (the compression steepened until "
                               "the labels crossed); add a [shock_capturing] section (docs/theory.md §11a), or a "
                               "smaller time.step if the wave is smooth", step=n, time=n * self.h,
                               cure="shock_capturing")
        return SolverError(f"{self._where(n)}: {text} {what}: the step is too large for this motion; "
                           "try a smaller time.step", step=n, time=n * self.h)

    def predictor(self, rest=False):
        """z extrapolated from the last step: tube q_n + h v, the last lam; the rod's last b and xi
        (exact for a rigid rotation).  ``rest``: the level itself (no motion), the fallback start."""
        m, st = self.model, self.state
        k = 0.0 if rest else 1.0
        parts = []
        if m.tube is not None:
            parts += [st.q[m.tube_q] + k * self.h * st.v[m.tube_p], st.lam[m.tube_lam]]
        if m.rod is not None:
            g = k * st.v[m.rod_p].reshape(2, m.N + 1, 3)
            parts += [np.concatenate([g[0], g[1]], axis=1)[m.rod.mask], st.lam[m.rod_lam]]
        return np.concatenate(parts) if parts else np.empty(0)

    def _label_problem(self, q0, z, midpoint=True):
        """A label that folds the lattice or leaves the tube at the step's evaluation point, or None."""
        t = self.model.tube
        if t is None or not t.has_fluid:
            return None
        pt = self.action.point(q0, z)
        q = 0.5 * (pt.q0 + pt.q1) if midpoint and self.action.name == "midpoint" else pt.q1
        return t.label_problem(t.config(np.concatenate([q, pt.lam])))

    def _solve(self, st, n1):
        sch = self.action
        z0 = self.predictor()
        if sch.explicit():
            # affine residual, constant diagonal Jacobian: one solve is exact (Stormer-Verlet)
            F0 = sch.residual(st.q, st.p, z0)
            return z0 - sch.jacobian(st.q, z0).diagonal() ** -1 * F0, 1, 1, 0
        F = lambda z: sch.residual(st.q, st.p, z)  # noqa: E731
        Jf = lambda z: sch.jacobian(st.q, z)  # noqa: E731
        opt = self._newton_options()
        res = newton(F, Jf, z0, self.scale, self.tol, opt["max_iter"], self._factor, rate_refresh=opt["rate_refresh"],
                     chord_iterations=opt["chord_iterations"], polish=opt["polish"], offset=self.offset)
        if not res.converged and (res.iterations == 0 or "not finite" in res.message):
            # the extrapolated predictor, or an iterate from it, left the lattice's domain (e.g. folds a label
            # at a shock's start-up): start again from the level itself, at rest
            self._factor = None
            z_rest = self.predictor(rest=True)
            # damped full Newton: it backs off from iterates outside the domain instead of stopping there
            res2 = newton_damped(F, Jf, z_rest, self.scale, self.tol, 4 * self.max_iter)
            self._fallback = True
            res2.iterations += res.iterations
            res2.n_residual += res.n_residual
            res2.n_jacobian += res.n_jacobian
            res = res2
        if not res.converged and opt["damped_fallback"]:
            # a poor extrapolation (e.g. stiff modes that the midpoint rule flips every step): retry with a
            # damped full Newton from the extrapolation, then from rest
            self._fallback = True
            res2 = newton_damped(F, Jf, z0, self.scale, self.tol, 4 * self.max_iter)
            if not res2.converged:
                res2 = newton_damped(F, Jf, self.predictor(rest=True), self.scale, self.tol, 4 * self.max_iter)
            res2.n_residual += res.n_residual
            res2.n_jacobian += res.n_jacobian
            res2.iterations += res.iterations
            res = res2
            self._factor = None
        if not res.converged:
            self._factor = None
            # an iterate outside the lattice's domain gives a non-finite residual or Jacobian: name the label
            problem = self._label_problem(st.q, res.z)
            if problem is not None:
                where = (f"in Newton iterate {res.iterations}" if res.iterations else
                         "at the start of the step (from the last velocity extrapolated, and from rest)")
                raise self._folded(n1, problem, where)
            advice = ("the step's equations are singular (a redundant support or constraint?): a smaller time.step "
                      "will not help" if "singular" in res.message else "try a smaller time.step")
            raise SolverError(
                f"Newton failed at {self._where(n1)}: {res.message}; "
                f"scaled update {res.error:.3g}, contraction rate {res.rate:.3g} after {res.iterations} iterations; "
                f"{advice}", step=n1, time=n1 * self.h, residual=res.error, rate=res.rate)
        if res.message != "damped Newton":
            self._factor = res.factor
        z = res.z
        if self._polishes():
            z = sch.rigid_polish(st.q, st.p, z)
        return z, res.iterations, res.n_residual, res.n_jacobian

    #: polish a free rod's step solution in the six rigid directions (Step.rigid_polish; docs/theory.md §10.6,
    #: "Momenta to round-off"); False: Newton's solution as it is (the floor before, for comparison)
    rigid_polish = True

    def _polishes(self):
        """A free rod with open ends (a support or a period breaks the rigid motions; open tube ends let momentum in)."""
        rod = self.model.rod
        return bool(self.rigid_polish and rod is not None and rod.free and not rod.periodic and not self.open
                    and not (rod.paper_measure and np.any(rod.g)))  # (Step.point: no increments there)

    def _step_velocity(self, q0, z, pt):
        """The predictor's data of this step: tube (q1 - q0)/h; rod b and xi on every node."""
        m = self.model
        parts = []
        if m.tube is not None:
            parts.append((z[m.tube_z][:m.tube.nq] - q0[m.tube_q]) / self.h)
        if m.rod is not None:
            parts += [np.einsum("nji,nj->ni", pt.Lam_n, pt.r_1 - pt.r_n).ravel(), pt.xi.ravel()]
        return np.concatenate(parts) if parts else np.empty(0)

    def step(self, state):
        """``(next state, StepReport)``: the step at h; where it fails (Newton, a frame turning by more than 90
        degrees, a folded lattice) and step control is on, two steps of h/2 instead (docs/theory.md §4b)."""
        if state is not self._state:
            self.state = state
        self._last = self
        start = self._state
        try:
            return self._step_at_h()
        except SolverError as exc:
            if not self.adaptive or self.depth >= MAX_HALVINGS:
                raise self._final(exc) from None
            failure = exc
        self.state = start  # (the model's evolving data back to the level: a heating force may have run)
        half = self._half_stepper()
        try:
            half.state = self._rescaled(start, 0.5, half.h)
            mid, r1 = half.step(half.state)
            end, r2 = half.step(mid)
        except SolverError:
            self.state = start
            raise self._final(failure) from None
        new = self._rescaled(end, 2.0, self.h)
        new.n, new.t = start.n + 1, (start.n + 1) * self.h
        self.state = new  # (the setter rebuilds this step for a lattice the half steps changed: open ends)
        self._last = half._last
        self._factor = None
        return new, StepReport(r1.iterations + r2.iterations, r1.n_residual + r2.n_residual,
                               r1.n_jacobian + r2.n_jacobian, True, halved=True)

    def _final(self, exc):
        """The failure that ends the run: at the top step of a midpoint or trapezoidal run, with the energy-momentum
        scheme named where it covers the scene (varint.schemes.limits.with_scheme_hint)."""
        if self.depth or self.scheme_name == "energy-momentum":
            return exc
        return with_scheme_hint(self.model, exc)

    def _half_stepper(self):
        if self._half is None:
            self._half = VariationalStepper(self.model, 0.5 * self.h, self.action.name, self.tol, self.max_iter,
                                            self._state, self.extra_forces, depth=self.depth + 1,
                                            scheme_name=self.scheme_name)
            self._half.floating_origin, self._half.rigid_polish = self.floating_origin, self.rigid_polish
        return self._half

    def _rescaled(self, st, factor, h):
        """A copy of ``st`` whose predictor data are for steps of ``h``: the rod's per-step increments b, xi scale by
        ``factor`` (the tube's are velocities); its level n and time as the stepper of ``h`` counts them."""
        new = st.copy()
        m = self.model
        if m.rod is not None:
            new.v[m.rod_p] *= factor
        new.n = int(round(st.t / h))
        return new

    def monitors(self):
        # the last step's own stepper evaluates its energy (a halved step's: the half stepper's discrete action)
        return LevelMonitors.monitors(self._last) if self._last is not self else LevelMonitors.monitors(self)

    def fields(self):
        return LevelMonitors.fields(self._last) if self._last is not self else LevelMonitors.fields(self)

    def _step_at_h(self):
        if self.compiled is not None:
            self.compiled.floating_origin = self.floating_origin  # a test may switch the floating origin off after start
            new = self.compiled.step(self._state)
            last = self.compiled.last
            self.state = new
            return new, StepReport(last["iterations"], last["n_residual"], last["n_jacobian"], bool(last["fallback"]))
        st = self._state
        m = self.model
        n1 = st.n + 1
        self._fallback = False
        if self.open:
            t = m.tube
            if getattr(t, "level_constraint", False):  # the first step takes half of level 0's impulse (§13.8)
                t.level_weight = 0.5 if st.n == 0 else 1.0
            if t.n_fixed:  # the piston's position at the step's midpoint (the potential is evaluated there)
                t.c0[0] = 0.5 * (t.piston + t.piston_after(self.h))
        z, iters, nres, njac = self._solve(st, n1)
        problem = self._label_problem(st.q, z, midpoint=False)
        if problem is not None:
            self._factor = None
            raise self._folded(n1, problem, "at the new time level")
        pt = self.action.point_and_frames(st.q, z)  # the accepted step's two levels, computed once
        if m.rod is not None:
            turn = np.linalg.norm(pt.xi, axis=1)
            if np.max(turn) > XI_MAX:
                # Newton found a solution whose frames turn by more than 90 degrees in one step: either the
                # step cannot resolve the rotation or the iteration landed on a spurious root (energy off
                # by O(1) in tests).  Neither is a result to keep.
                j = int(np.argmax(turn))
                self._factor = None
                raise chart_limit_error(m, n1, self.h, j, turn[j])
        p1 = self.action.momentum_plus(st.q, z, pt)
        for force in self.action.forces:
            if hasattr(force, "after_step"):  # e.g. a viscosity heating the parcels it slowed
                force.after_step(pt)
        q1 = self.action.retract(st.q, z, floating_origin=self.floating_origin, pt=pt)
        v = self._step_velocity(st.q, z, pt)
        lam = np.concatenate([z[m.tube_z][m.tube.nq:] if m.tube is not None else np.empty(0), z[m.rod_lam_z]])
        if self.open:
            if m.coupled:
                self._oc_fluxes(st.q, st.p, z)
            else:
                self._open_fluxes(st.q, st.p, z)
            new = State(n1, n1 * self.h, q1, p1, lam, v, st.q.copy(), None)
            (self._oc_update if m.coupled else self._open_update)(new)
            new.data = m.state_data()
            self._state = new
        else:
            self.state = State(n1, n1 * self.h, q1, p1, lam, v, st.q.copy(), m.state_data())
        return self._state, StepReport(iters, nres, njac, self._fallback)
