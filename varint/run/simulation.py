"""The driver: :class:`Simulation` steps a model in time with its scheme and reports monitors and fields.

The step itself is the scheme's (:mod:`varint.schemes`); the state it takes and returns is
:class:`varint.schemes.state.State`.
"""

from __future__ import annotations

import logging
import math

import numpy as np
import scipy.sparse as sp

from ..errors import SolverError
from ..lattice.lie import cay
from ..schemes.newton import RATE_REFRESH, newton, newton_damped
from .open_ends import OpenEndsStepping
from ..terms.rod import POLISH_ROD, RATE_REFRESH_ROD, XI_MAX, unpack_level
from ..schemes.midpoint import make_scheme
from ..schemes.state import State, StepStats


__all__ = ["Simulation"]

log = logging.getLogger(__name__)


def _refuse_open(model, scheme):
    """What open ends cannot run with yet, in one line each (docs/theory.md §13.7)."""
    t, sc = model.tube, model.scene
    if model.rod is not None and not t.open:
        raise SolverError("fluid.ends: open ends on a [rod] (the coupled tube) run with an incompressible liquid in a rigid "
                          "tube (no [wall]) and a velocity inlet in this version")
    if model.rod is not None and t.p_out != t.p_ext:
        raise SolverError("fluid.ends.outflow_pressure: open ends on a [rod] run with a free jet (the outlet at "
                          "environment.external_pressure) in this version")
    if t.has_wall and not t.wall_dynamic:
        raise SolverError("fluid.ends: open ends with a quasistatic [wall] are not available in this version; a rigid "
                          "tube or a dynamic wall runs")
    if t.gx != 0.0 and model.rod is None:
        raise SolverError("environment.gravity: gravity along a straight tube with open ends is not available in this "
                          "version (on a [rod] it is)")
    if getattr(sc, "shock_capturing", None) is not None:
        raise SolverError("shock_capturing: not available with open ends in this version")
    if (scheme or sc.time.scheme) != "midpoint":
        raise SolverError("time.scheme: open ends need 'midpoint' (the piston's position is taken at the step's midpoint)")
    if t.inflow == "velocity" and t.U_in * sc.time.step > 0.5 * t.ell_in:
        raise SolverError(f"time.step: the inflow moves {t.U_in * sc.time.step:.3g} m per step, more than half an inflow "
                          f"parcel ({0.5 * t.ell_in:.3g} m); reduce time.step or fluid.parcels")


class Simulation(OpenEndsStepping):
    """Public step API: ``sim.step()`` advances one time step; ``sim.state`` is the current level."""

    def __init__(self, model, h=None, scheme=None, tol=None, max_iter=None, state=None):
        tcfg = model.scene.time
        if model.tube is not None and model.tube.open_ends:
            _refuse_open(model, scheme)
        self.model = model
        self._built_version = None  # open ends: the lattice version the step was built for
        self.h = float(h if h is not None else tcfg.step)
        #: the energy-momentum step of the rod alone (varint/schemes/em_rod.py, docs/theory.md §12a) or of the coupled tube
        #: (varint/schemes/em_tube.py, §12b); the Step below then only lays out the state and the monitors
        self._em = None
        if (scheme or tcfg.scheme) == "energy-momentum":
            if model.coupled:
                from ..schemes.em_tube import TubeEMStep

                self._em = TubeEMStep(model, self.h, tol=min(tcfg.newton_tol, 1e-12) if tol is None else tol)
            else:
                from ..schemes.em_rod import RodEMStep

                self._em = RodEMStep(model, self.h, tol=min(tcfg.newton_tol, 1e-13) if tol is None else tol)
            scheme = "midpoint"
        self.scheme = make_scheme(model, self.h, scheme)
        self.tol = tol if tol is not None else tcfg.newton_tol
        self.max_iter = max_iter if max_iter is not None else tcfg.max_iterations
        if state is None and model.initial_data:
            model.set_state_data(model.initial_data)  # a rerun of the model starts from t = 0's data, not a heated run's
        self.state = state if state is not None else State(0, 0.0, *model.initial_state(self.h), data=model.state_data())
        if self.open and state is None:
            self._open_start()
        self.stats = StepStats()
        self._factor = None
        self.scale, self.offset = self._scales()
        # A free rod can travel far from the origin; positions are then kept relative to a floating
        # origin (moved with node 0 each step, exactly, on a binary grid) so that strains and forces
        # are computed from O(L) numbers: with absolute coordinates their round-off grows like eps |r|
        # and a rod drifting 3.7 km lost its angular momentum to 1e-8 (docs/validation.md).
        self.floating_origin = model.rod is not None and model.rod.free
        # the rod alone steps through one compiled routine (varint/schemes/rod_compiled.py, docs/theory.md §9 "The fast rod
        # step"): the same discrete equations, 4-15x cheaper per step; everything else through Step below
        self._fast = None
        if self.scheme.name == "midpoint" and not self.open and self._em is None:
            from ..schemes.rod_compiled import FastRodStep, supports

            if supports(model) is None:
                self._fast = FastRodStep(model, self.h, self.tol, self.max_iter)

    @property
    def state(self):
        """The current level (:class:`State`)."""
        return self._state

    @state.setter
    def state(self, st):
        # a checkpoint written before the rod's floating origin existed gains it (varint.model.model.Model.upgrade_level)
        st.q = self.model.upgrade_level(st.q)
        if st.q_prev is not None:
            st.q_prev = self.model.upgrade_level(st.q_prev)
        if st.data:
            self.model.set_state_data(st.data)
        self._state = st
        if self.open and self.model.tube.lattice_version != self._built_version:
            self._rebuild()

    @property
    def open(self):
        """True for the straight tube with open ends (docs/theory.md §13)."""
        t = self.model.tube
        return t is not None and getattr(t, "open", False)

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

    def _fast_step(self):
        """One step of the rod alone by :class:`varint.schemes.rod_compiled.FastRodStep` (its own fallback: this stepper's
        damped Newton), with the statistics the monitors report."""
        self._fast.floating_origin = self.floating_origin  # a test may switch the floating origin off after start
        new = self._fast.step(self.state)
        s, last = self.stats, self._fast.last
        s.iterations, s.n_residual, s.n_jacobian = last["iterations"], last["n_residual"], last["n_jacobian"]
        s.total_iterations += last["iterations"]
        s.total_jacobians += last["n_jacobian"]
        s.fallbacks += int(last["fallback"])
        self.state = new
        return self.state

    def invalidate_jacobian(self):
        """Forget the reused factorisation (done at checkpoints so a restart repeats the same arithmetic)."""
        self._factor = None
        if getattr(self, "_fast", None) is not None:
            self._fast.invalidate()
        if getattr(self, "_em", None) is not None:
            self._em._lu = None

    def _where(self, n):
        return f"step {n} (t = {n * self.h:.6g} s)"

    def _folded(self, n, problem, what):
        k, text = problem
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
        pt = self.scheme.point(q0, z)
        q = 0.5 * (pt.q0 + pt.q1) if midpoint and self.scheme.name == "midpoint" else pt.q1
        return t.label_problem(t.config(np.concatenate([q, pt.lam])))

    def _solve(self, st, n1):
        sch = self.scheme
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
            self.stats.fallbacks += 1
            res2.iterations += res.iterations
            res2.n_residual += res.n_residual
            res2.n_jacobian += res.n_jacobian
            res = res2
        if not res.converged and opt["damped_fallback"]:
            # a poor extrapolation (e.g. stiff modes that the midpoint rule flips every step): retry with a
            # damped full Newton from the extrapolation, then from rest
            self.stats.fallbacks += 1
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

    def step(self):
        if self._fast is not None:
            return self._fast_step()
        if self._em is not None:
            self.state = self._em.step_state(self.state, self.model)
            s, last = self.stats, self._em.last
            s.iterations, s.n_jacobian = last["iterations"], last["jacobians"]
            s.total_iterations += last["iterations"]
            s.total_jacobians += last["jacobians"]
            s.fallbacks += int(last["fallback"] > 0)  # 1: full Newton restarted; 2: solved from two half steps
            return self.state
        st = self.state
        m = self.model
        n1 = st.n + 1
        if self.open:
            t = m.tube
            if t.n_fixed:  # the piston's position at the step's midpoint (the potential is evaluated there)
                t.c0[0] = t.piston + 0.5 * self.h * t.U_in
        z, iters, nres, njac = self._solve(st, n1)
        problem = self._label_problem(st.q, z, midpoint=False)
        if problem is not None:
            self._factor = None
            raise self._folded(n1, problem, "at the new time level")
        pt = self.scheme.point_and_frames(st.q, z)  # the accepted step's two levels, computed once
        if m.rod is not None:
            turn = np.linalg.norm(pt.xi, axis=1)
            if np.max(turn) > XI_MAX:
                # Newton found a solution whose frames turn by more than 90 degrees in one step: either the
                # step cannot resolve the rotation or the iteration landed on a spurious root (energy off
                # by O(1) in tests).  Neither is a result to keep.
                j = int(np.argmax(turn))
                deg = math.degrees(2.0 * math.atan(0.5 * turn[j]))
                self._factor = None
                raise SolverError(f"{self._where(n1)}: node {j} turns by {deg:.0f} degrees in one "
                                  "step (more than 90); reduce time.step", step=n1, time=n1 * self.h)
        p1 = self.scheme.momentum_plus(st.q, z, pt)
        for force in m.forces:
            if hasattr(force, "after_step"):  # e.g. a viscosity heating the parcels it slowed
                force.after_step(pt)
        q1 = self.scheme.retract(st.q, z, floating_origin=self.floating_origin, pt=pt)
        v = self._step_velocity(st.q, z, pt)
        lam = np.concatenate([z[m.tube_z][m.tube.nq:] if m.tube is not None else np.empty(0), z[m.rod_lam_z]])
        if self.open:
            if m.coupled:
                self._oc_fluxes(st.q, st.p, z)
            else:
                self._open_fluxes(st.q, z)
            new = State(n1, n1 * self.h, q1, p1, lam, v, st.q.copy(), None)
            (self._oc_update if m.coupled else self._open_update)(new)
            new.data = m.state_data()
            self._state = new
        else:
            self.state = State(n1, n1 * self.h, q1, p1, lam, v, st.q.copy(), m.state_data())
        s = self.stats
        s.iterations, s.n_residual, s.n_jacobian = iters, nres, njac
        s.total_iterations += iters
        s.total_jacobians += njac
        return self.state

    def _step_velocity(self, q0, z, pt):
        """The predictor's data of this step: tube (q1 - q0)/h; rod b and xi on every node."""
        m = self.model
        parts = []
        if m.tube is not None:
            parts.append((z[m.tube_z][:m.tube.nq] - q0[m.tube_q]) / self.h)
        if m.rod is not None:
            parts += [np.einsum("nji,nj->ni", pt.Lam_n, pt.r_1 - pt.r_n).ravel(), pt.xi.ravel()]
        return np.concatenate(parts) if parts else np.empty(0)

    # -- monitors -------------------------------------------------------------

    def monitors(self):
        """Invariants and energies at the current level (each part's, summed where they add up)."""
        if self.open:
            return self._oc_monitors() if self.model.coupled else self._open_monitors()
        if self.model.coupled:
            return self._coupled_monitors()
        # one part: the tube's blocks on the fixed centreline, or the rod alone
        out = self._tube_monitors() if self.model.tube is not None else self._rod_monitors()
        out["newton_iterations"] = self.stats.iterations
        return out

    def _tube_monitors(self):
        """The tube's energies, mass, axial momentum, entropy and constraint.

        Energy: without algebraic unknowns, H(q_n, p_n) = 1/2 p M^-1 p + U(q_n) at the level (exactly
        conserved by the midpoint rule on linear problems, whatever h); with them (quasistatic wall,
        incompressible fluid) the energy of the step that ended here, 1/2 v M v + U(midpoint), because
        their half-level unknowns have no value at a level.  Record 0: the initial data.
        """
        m, st = self.model, self.state
        t = m.tube
        q, p, v_st = st.q[m.tube_q], st.p[m.tube_p], st.v[m.tube_p]
        out = {}
        if t.nlam == 0 or st.q_prev is None:
            pot = t.energies(t.config(np.concatenate([q, st.lam[m.tube_lam]])))
            v = p / np.where(t.mass > 0, t.mass, 1.0) if st.q_prev is not None else v_st
        else:
            pot = self.scheme.step_energies(st.q_prev, np.concatenate([q, st.lam[m.tube_lam], np.zeros(m.nz - m.tube_z.stop)]))
            v = v_st
        kin = 0.5 * t.mass * v * v
        kf = float(np.sum(kin[t.layout["s"]])) if "s" in t.layout else 0.0
        kw = float(np.sum(kin[t.layout["R"]])) if t.wall_dynamic else 0.0
        out["kinetic_energy"] = kf + kw
        out["energy_fluid_kinetic"] = kf
        out["energy_wall_kinetic"] = kw
        for k, val in pot.items():
            out[f"energy_{k}"] = val
        out["energy"] = out["kinetic_energy"] + sum(pot.values())
        # the mass the state holds: density field times the parcel volumes of the configuration (for an
        # incompressible fluid at the step's midpoint, where its volume constraint is imposed)
        out["mass"] = t.fluid_mass(self._mass_config()) if t.has_fluid else 0.0
        mom = np.zeros(3)
        if "s" in t.layout:
            mom[0] = float(np.sum(p[t.layout["s"]]))
        out["linear_momentum"] = mom
        # every fluid label moves along the x axis through the origin: r x p = 0
        out["angular_momentum"] = np.zeros(3)
        out["newton_iterations"] = self.stats.iterations
        if t.has_fluid:
            out["entropy"] = float(np.sum(t.m * t.S))
            if t.incompressible:
                out["constraint_residual"] = float(np.max(np.abs(t.volumes(self._mass_config()) / t.V0 - 1.0)))
        return out

    def _mass_config(self):
        """The tube's configuration at the level, or at the last step's midpoint for an incompressible fluid."""
        m, st = self.model, self.state
        t = m.tube
        q = st.q[m.tube_q]
        if t.incompressible and st.q_prev is not None:
            q = 0.5 * (q + st.q_prev[m.tube_q])
        return t.config(np.concatenate([q, st.lam[m.tube_lam]]))

    def _rod_monitors(self):
        """The rod's level energy H(q_n, pi_n), momenta about the origin and the centre of mass, frames."""
        m, st = self.model, self.state
        rod = m.rod
        N = rod.N
        Lam, r, origin = unpack_level(st.q[m.rod_q], N)
        pp = st.p[m.rod_p]
        # supported components carry reaction impulses in D2 L_d, not momentum: leave them out
        p = pp[: 3 * (N + 1)].reshape(N + 1, 3) * rod.mask[:, :3]
        Pi = pp[3 * (N + 1):].reshape(N + 1, 3) * rod.mask[:, 3:]
        if rod.constrained:
            # the level momenta D2 L_d' lack the level's constraint impulse h ds G^T lambda^n (no motion, but
            # not tangent either): the kinetic energy is that of their part tangent to the constraint (p - G^T mu with
            # G M^-1 (p - G^T mu) = 0, the projection of RATTLE)
            p, Pi = self._tangent_momenta(Lam, r, p, Pi)
        pot = rod.level_energy(Lam, r, p, Pi, origin)
        out = {"kinetic_energy": pot.pop("kinetic")}
        for k, v in pot.items():
            out[f"energy_{k}"] = v
        out["energy"] = out["kinetic_energy"] + sum(pot.values())
        out["mass"] = float(np.sum(rod.node_mass))
        out["linear_momentum"] = p.sum(0)
        # about the (fixed) origin: origin x P + sum (r - origin) x p + Lambda Pi, each part from O(L) numbers
        spin = np.einsum("nij,nj->i", Lam, Pi)
        out["angular_momentum"] = np.cross(origin, p.sum(0)) + np.cross(r, p).sum(0) + spin
        # about the centre of mass: the well-conditioned one for a rod far from the origin (there the
        # difference angular_momentum - r_c x P cancels large numbers)
        out["angular_momentum_cm"] = np.cross(r - rod.centre_of_mass(r), p).sum(0) + spin
        out["frame_orthogonality"] = float(np.max(np.abs(np.swapaxes(Lam, 1, 2) @ Lam - np.eye(3))))
        if rod.constrained:
            from ..terms.rod_constraint import element_strain_residual

            out["rod_constraint_residual"] = element_strain_residual(rod, Lam, r)
        out["newton_iterations"] = self.stats.iterations
        if self._em is not None:  # the energy-momentum step's own conserved energy and momenta (rod_em.py, tube_em.py)
            out.update(self._em.monitors())
        return out

    def _tangent_momenta(self, Lam, r, p, Pi):
        """The momenta's part tangent to Gamma = chi at the level, in the kinetic metric (reference measure)."""
        import scipy.sparse.linalg as spla

        from ..terms.rod_constraint import constraint_jacobian

        rod = self.model.rod
        mask = rod.mask
        G = constraint_jacobian(Lam, r, rod.ds, rod.ncomp, mask)
        minv = np.concatenate([np.repeat(1.0 / rod.node_mass[:, None], 3, axis=1),
                               1.0 / rod.node_inertia], axis=1)[mask]
        pa = np.concatenate([p, Pi], axis=1)[mask]
        A = (G @ sp.diags(minv) @ G.T).tocsc()
        mu = spla.spsolve(A, G @ (minv * pa)) if A.shape[0] else np.zeros(0)
        full = np.zeros((rod.N + 1, 6))
        full[mask] = pa - G.T @ mu
        return full[:, :3], full[:, 3:]

    # -- the coupled tube ------------------------------------------------------------

    def _coupled_levels(self):
        """(level-n configuration of the tube, rod frames, positions, origin) at the current level."""
        m, st = self.model, self.state
        t = m.tube
        cfg = t.config(np.concatenate([st.q[m.tube_q], st.lam[m.tube_lam]]))
        Lam, r, origin = unpack_level(st.q[m.rod_q], m.N)
        return cfg, Lam, r, origin

    @property
    def _n_kernel_nodes(self):
        rod = self.model.rod
        return rod.N if rod.periodic else rod.N + 1

    def _coupled_volumes(self, cfg, Lam, r):
        """The parcels' stretched volumes at one level (docs/theory.md §10.3)."""
        from ..terms.coupled import element_strains, stretched_volumes_of

        t = self.model.tube
        return stretched_volumes_of(cfg.s, cfg.R, element_strains(Lam, r, t.ds)[0], t.ds, t.periodic)

    def _coupled_monitors(self):
        """Energy, momenta, mass and entropy of the coupled tube (docs/theory.md §10.5, §10.6).

        Energy: the fluid's kinetic metric depends on the labels, so the energy is that of the step that ended
        at this level, E = K(step) + U(midpoint data) = 2 K(step) - L_d / h, with K(step) the kinetic terms'
        share of L_d over h; record 0: the initial data's kinetic energy (the Legendre map of
        :meth:`varint.model.model.Model.initial_legendre`) plus the potential at the level.  Momenta: the full nodal
        momenta (they carry the fluid's, §10.6) about the origin and the centre of mass of rod and fluid.
        """
        from ..terms.coupled import element_strains, stretched_volumes_of

        if self._em is not None:  # the energy-momentum step's own energy, momenta, volumes (varint/schemes/em_tube.py)
            out = self._em.monitors()
            out["newton_iterations"] = self.stats.iterations
            return out
        m, st, h = self.model, self.state, self.h
        t, rod = m.tube, m.rod
        N = rod.N
        cfg, Lam, r, origin = self._coupled_levels()
        sch = self.scheme
        fluid = next(x for x in sch.terms if x.name == "fluid")
        out = {}
        if t.nlam == 0 or st.q_prev is None:
            # the level energy H(q_n, p_n): kinetic from the momenta through the kinetic metric, potential at the level
            Kf, Kr, Kw = self._coupled_level_kinetic(cfg, Lam, r)
            z = sch.unknowns(st.q, st.q, st.lam)
            U = -sum(x.value(sch.point(st.q, z)) for x in sch.terms) / h
            o_ref = origin
        else:
            # with half-level unknowns (multipliers, quasistatic radii) the energy of the step that ended here
            z = sch.unknowns(st.q_prev, st.q, st.lam)
            pt = sch.point(st.q_prev, z)
            L = sum(x.value(pt) for x in sch.terms)
            Kf = fluid.kinetic_value(pt) / h
            kin = 0.5 * (rod.section.rhoA * np.sum((pt.r_1 - pt.r_n) ** 2, axis=1)
                         + np.sum(rod.section.inertia * pt.xi * pt.xi, axis=1)) / h ** 2
            if rod.paper_measure:  # the kernel weights each element's kinetic density by |Gammabar_e|
                Om0, Ga0 = rod.strains(pt.Lam_n, pt.r_n)
                Om1, Ga1 = rod.strains(pt.Lam_n @ cay(pt.xi), pt.r_1)
                mu_e = np.linalg.norm(0.5 * (Ga0 + Ga1), axis=1)
                Kr = float(np.sum(rod.ds * mu_e * 0.5 * (kin[:-1] + kin[1:])))
            else:
                Kr = float(np.sum(rod.w * kin))
            Kw = 0.5 * float(np.sum(t.mass * st.v[m.tube_p] ** 2)) if t.wall_dynamic else 0.0
            U = (Kf + Kr + Kw) - L / h
            o_ref = unpack_level(st.q_prev[m.rod_q], N)[2]
        # positions in L_d are relative to the floating origin of the step's level n: the potentials linear in r
        # (gravity, the tip force) take the origin's part here
        mbar = t.label_mass_all
        M_tot = float(np.sum(rod.node_mass) + np.sum(mbar))
        M_grav = M_tot
        if rod.paper_measure:  # the rod's gravitational mass is rho A sum_e ds |Gamma_e| at the evaluation point
            if t.nlam == 0 or st.q_prev is None:
                _, Ga = rod.strains(Lam, r)
            else:
                Om0, Ga0 = rod.strains(pt.Lam_n, pt.r_n)
                Om1, Ga1 = rod.strains(pt.Lam_n @ cay(pt.xi), pt.r_1)
                Ga = 0.5 * (Ga0 + Ga1)
            M_grav = float(rod.section.rhoA * np.sum(rod.ds * np.linalg.norm(Ga, axis=1)) + np.sum(mbar))
        U -= M_grav * float(np.dot(rod.g, o_ref)) + float(np.dot(rod.force, o_ref))
        out["kinetic_energy"] = Kf + Kr + Kw
        out["energy_fluid_kinetic"] = Kf
        out["energy_rod_kinetic"] = Kr
        out["energy_wall_kinetic"] = Kw
        out["energy_potential"] = U
        out["energy"] = Kf + Kr + Kw + U
        # mass from the state: density field times the stretched parcel volumes (incompressible: where the
        # constraint holds, at the level for a liquid held at the levels, else at the last step's midpoint)
        V = self._coupled_volumes(cfg, Lam, r)
        if t.incompressible and st.q_prev is not None and not fluid.level_constraint:
            s0, R0, s1, R1, _, Lam1 = fluid.levels(sch.point(st.q_prev, sch.unknowns(st.q_prev, st.q, st.lam)))
            Lp, rp, op = unpack_level(st.q_prev[m.rod_q], N)
            G0, _, _ = element_strains(Lp, rp + op - origin, t.ds)
            G1, _, _ = element_strains(Lam, r, t.ds)
            Vbar = stretched_volumes_of(0.5 * (s0 + s1), 0.5 * (R0 + R1), 0.5 * (G0 + G1), t.ds, t.periodic)
            out["mass"] = float(np.sum(rod.node_mass) + np.sum(t.m / t.V0 * Vbar))
            out["constraint_residual"] = float(np.max(np.abs(Vbar / t.V0 - 1.0)))
        else:
            rho = t.m / t.V0 if t.incompressible else t.m / V
            out["mass"] = float(np.sum(rod.node_mass) + np.sum(rho * V))
            if t.incompressible:
                out["constraint_residual"] = float(np.max(np.abs(V / t.V0 - 1.0)))
        pp = st.p[m.rod_p]
        p = pp[: 3 * (N + 1)].reshape(N + 1, 3) * rod.mask[:, :3]
        Pi = pp[3 * (N + 1):].reshape(N + 1, 3) * rod.mask[:, 3:]
        P = p.sum(0)
        spin = np.einsum("nij,nj->i", Lam, Pi)
        out["linear_momentum"] = P
        out["angular_momentum"] = np.cross(origin, P) + np.cross(r, p).sum(0) + spin
        X = m.centreline(cfg.s, r)[3]
        c = (np.sum(rod.node_mass[:, None] * r, axis=0) + np.sum(mbar[:, None] * X, axis=0)) / M_tot
        out["angular_momentum_cm"] = np.cross(r - c, p).sum(0) + spin
        out["frame_orthogonality"] = float(np.max(np.abs(np.swapaxes(Lam, 1, 2) @ Lam - np.eye(3))))
        if rod.constrained:
            from ..terms.rod_constraint import element_strain_residual

            out["rod_constraint_residual"] = element_strain_residual(rod, Lam, r)
        if t.eos is not None:
            out["entropy"] = float(np.sum(t.m * t.S))
        out["newton_iterations"] = self.stats.iterations
        return out

    def _coupled_level_kinetic(self, cfg, Lam, r):
        """(fluid, rod, wall) kinetic energy 1/2 p.M(q)^-1.p at the level, from the discrete momenta.

        The kinetic metric of docs/theory.md §10.5: rho A w_j on the nodal velocities, the section inertia on
        the body angular velocities, a w_j on the radial ones, and the fluid's 1/2 sum_k mbar_k |Xdot_k|^2,
        Xdot_k = sum_i N_i(s_k) rdot_i + X'_k sdot_k, which couples nodes and labels.  Restricted to the
        unknowns that move (supported components and the closed ends' labels hold none).  The fluid's share
        is the energy of the labels' velocities Xdot that the solve gives.
        """
        import scipy.sparse.linalg as spla

        m, st = self.model, self.state
        t, rod = m.tube, m.rod
        N, M = rod.N, t.M
        n1 = N + 1
        wmu = rod.w
        if rod.paper_measure:  # the rod's kinetic density is weighted by |Gamma_e| (RodPart.level_energy)
            _, Ga = rod.strains(Lam, r)
            mu = np.linalg.norm(Ga, axis=1)
            wmu = np.zeros(n1)
            wmu[:-1] += 0.5 * rod.ds * mu
            wmu[1:] += 0.5 * rod.ds * mu
        from ..terms.coupled import kinetic_metric_of

        nodes, Nw, _, _, dX, _ = m.centreline(cfg.s, r)
        # variables: per node [rdot (3), body omega (3)], then the labels' sdot; Xdot_k = sum_a N_a rdot + X'_k sdot_k
        nvar = 6 * n1 + M + 1
        Mf, Jx = kinetic_metric_of(nodes, Nw, dX, t.label_mass_all, n1)
        rod_diag = np.concatenate([np.repeat((rod.section.rhoA * wmu)[:, None], 3, axis=1),
                                   rod.section.inertia[None, :] * wmu[:, None]], axis=1).ravel()
        Mt = Mf + sp.diags(np.concatenate([rod_diag, np.zeros(M + 1)]))
        labels = np.arange(M + 1)[m.free_labels]
        active = np.concatenate([np.nonzero(rod.mask.ravel())[0], 6 * n1 + labels])
        pr = st.p[m.rod_p].reshape(2, n1, 3).transpose(1, 0, 2).reshape(-1)
        ps = np.zeros(M + 1)
        ps[labels] = st.p[m.tube_p][t.layout["s"]]
        pa = np.concatenate([pr, ps])[active]
        Maa = Mt[active][:, active].tocsc()
        if rod.constrained:
            # the level momenta carry half the step's constraint impulse: keep their part tangent to Gamma = chi
            # in this metric (the saddle-point solve of RATTLE's projection)
            from ..terms.rod_constraint import constraint_jacobian

            G = constraint_jacobian(Lam, r, rod.ds, rod.ncomp, rod.mask)
            G = sp.hstack([G, sp.csr_matrix((G.shape[0], len(active) - G.shape[1]))]).tocsr()
            K = sp.bmat([[Maa, G.T], [G, None]]).tocsc()
            va = spla.spsolve(K, np.concatenate([pa, np.zeros(G.shape[0])]))[: len(active)]
        else:
            va = spla.spsolve(Maa, pa) if len(pa) else np.zeros(0)
        vel = np.zeros(nvar)
        vel[active] = va
        Xdot = (Jx @ vel).reshape(M + 1, 3)
        Kf = 0.5 * float(np.sum(t.label_mass_all * np.sum(Xdot * Xdot, axis=1)))
        Kr = 0.5 * float(np.sum(rod_diag * vel[: 6 * n1] ** 2))
        Kw = 0.0
        if t.wall_dynamic:
            sl = t.layout["R"]
            pR = st.p[m.tube_p][sl]
            Kw = 0.5 * float(np.sum(pR * pR / t.mass[sl]))
        return Kf, Kr, Kw

    def fields(self):
        """Field values at the current level, keyed by HDF5 path under /fields."""
        if self.open:
            return self._oc_fields() if self.model.coupled else self._open_fields()
        m, st = self.model, self.state
        out = {}
        t = m.tube
        if m.coupled:
            cfg, Lam, r, origin = self._coupled_levels()
            V = self._coupled_volumes(cfg, Lam, r)
            rho = t.m / t.V0 if t.incompressible else t.m / V
            geo = m.centreline(cfg.s, r)
            out["fluid/s"] = cfg.s.copy()
            out["fluid/position"] = geo[3] + origin
            out["fluid/density"] = rho
            out["fluid/pressure"] = cfg.mu.copy() if t.incompressible else t.eos.pressure(rho, t.S)
            # the speed along the tube relative to it, |X'| ds/dt, of the last step (closed ends: 0)
            u = np.zeros(t.M + 1)
            u[m.free_labels] = st.v[m.tube_p][t.layout["s"]]
            if t.periodic:
                u[-1] = u[0]
            u *= np.linalg.norm(geo[4], axis=1)
            out["fluid/velocity"] = u
            out["fluid/entropy"] = t.S.copy()
            if t.has_wall:
                out["wall/R"] = t.full_radius(cfg)
                if t.wall_dynamic:
                    out["wall/velocity"] = st.v[m.tube_p][t.layout["R"]].copy()
            out["rod/r"] = r + origin
            out["rod/Lambda"] = Lam.copy()
            return out
        if t is not None:
            q = st.q[m.tube_q]
            cfg = t.config(np.concatenate([q, st.lam[m.tube_lam]]))
            if t.has_fluid:
                rho, p, u = t.fluid_fields(cfg, st.p[m.tube_p])
                out["fluid/s"] = cfg.s.copy()
                out["fluid/density"] = rho
                out["fluid/pressure"] = p
                out["fluid/velocity"] = u
                out["fluid/entropy"] = t.S.copy()
            if t.has_wall:
                out["wall/R"] = t.full_radius(cfg)
                if t.wall_dynamic:
                    vR = st.v[m.tube_p][t.layout["R"]]
                    out["wall/velocity"] = np.append(vR, vR[0]) if t.periodic else vR.copy()
        if m.rod is not None:
            Lam, r, origin = unpack_level(st.q[m.rod_q], m.N)
            out["rod/r"] = r + origin
            out["rod/Lambda"] = Lam.copy()
        return out
