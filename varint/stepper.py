"""The discrete Lagrangian of one time step, its stationarity conditions, and the stepper.

For a step n -> n+1 with q the inertial unknowns and lam the algebraic ones
(see :mod:`varint.model`), v = (q1 - q0)/h and constant diagonal mass M:

midpoint
    L_d(q0, q1, lam) = h [ 1/2 v.M.v - U(config((q0 + q1)/2, lam)) ]
trapezoidal (no algebraic unknowns)
    L_d(q0, q1) = h [ 1/2 v.M.v - 1/2 U(config(q0)) - 1/2 U(config(q1)) ]

The step solves, in position-momentum form (docs/theory.md §4),

    p_n + D1 L_d(q_n, q_{n+1}, lam) = 0,      D_lam L_d(q_n, q_{n+1}, lam) = 0,

for (q_{n+1}, lam_{n+1/2}) and sets p_{n+1} = D2 L_d.  These residuals *are*
components of the gradient of the discrete action sum_n L_d; the test suite
checks that against finite differences of :meth:`Scheme.discrete_lagrangian`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from .errors import SolverError
from .newton import newton

__all__ = ["Midpoint", "Trapezoidal", "make_scheme", "State", "Simulation"]

log = logging.getLogger(__name__)


class Scheme:
    """Shared pieces of the two quadratures."""

    name = "scheme"
    order = None  #: the declared order of accuracy in h; each scheme sets it

    def __init__(self, model, h):
        self.model = model
        self.h = float(h)
        nq, nz = model.nq, model.nz
        self.Bq = model.B[:, :nq]
        self.Bl = model.B[:, nq:]
        self.Mdiag = model.mass

    def _cfg(self, qpart, lam):
        return self.model.config(np.concatenate([qpart, lam]))

    def kinetic(self, q0, q1):
        v = (q1 - q0) / self.h
        return 0.5 * float(np.dot(self.Mdiag * v, v))


class Midpoint(Scheme):
    name = "midpoint"
    order = 2  #: global order in h (symmetric one-stage quadrature); asserted by tests/test_convergence.py

    def discrete_lagrangian(self, q0, q1, lam):
        cfg = self._cfg(0.5 * (q0 + q1), lam)
        return self.h * (self.kinetic(q0, q1) - self.model.potential(cfg))

    def _grad(self, q0, z):
        nq = self.model.nq
        q1, lam = z[:nq], z[nq:]
        cfg = self._cfg(0.5 * (q0 + q1), lam)
        return q1, lam, cfg, self.model.gradient(cfg)

    def residual(self, q0, p0, z):
        """[p_n + D1 L_d ; D_lam L_d] at z = concat(q_{n+1}, lam)."""
        q1, lam, cfg, g = self._grad(q0, z)
        h = self.h
        rq = p0 - self.Mdiag * (q1 - q0) / h - 0.5 * h * (self.Bq.T @ g)
        rl = -h * (self.Bl.T @ g)
        return np.concatenate([rq, rl])

    def jacobian(self, q0, z):
        nq = self.model.nq
        q1, lam = z[:nq], z[nq:]
        cfg = self._cfg(0.5 * (q0 + q1), lam)
        H = self.model.hessian(cfg)
        C = sp.hstack([0.5 * self.Bq, self.Bl]).tocsr()
        mass = np.concatenate([self.Mdiag / self.h, np.zeros(self.model.nlam)])
        return (-sp.diags(mass) - self.h * (C.T @ H @ C)).tocsc()

    def momentum_plus(self, q0, z):
        """p_{n+1} = D2 L_d(q_n, q_{n+1}, lam)."""
        q1, lam, cfg, g = self._grad(q0, z)
        return self.Mdiag * (q1 - q0) / self.h - 0.5 * self.h * (self.Bq.T @ g)

    def step_energies(self, q0, z):
        """Energy of the step: kinetic of v_{n+1/2} and each potential at the midpoint."""
        nq = self.model.nq
        cfg = self._cfg(0.5 * (q0 + z[:nq]), z[nq:])
        return self.model.energies(cfg)

    def explicit(self):
        return False


class Trapezoidal(Scheme):
    name = "trapezoidal"
    order = 2  #: global order in h (Stormer-Verlet); asserted by tests/test_convergence.py

    def __init__(self, model, h):
        super().__init__(model, h)
        if model.nlam:
            raise ValueError("the trapezoidal scheme needs every unknown to carry inertia")

    def discrete_lagrangian(self, q0, q1, lam=None):
        e = np.empty(0)
        U0 = self.model.potential(self._cfg(q0, e))
        U1 = self.model.potential(self._cfg(q1, e))
        return self.h * (self.kinetic(q0, q1) - 0.5 * (U0 + U1))

    def _force(self, q):
        return self.Bq.T @ self.model.gradient(self._cfg(q, np.empty(0)))

    def residual(self, q0, p0, z):
        return p0 - self.Mdiag * (z - q0) / self.h - 0.5 * self.h * self._force(q0)

    def jacobian(self, q0, z):
        return sp.diags(-self.Mdiag / self.h).tocsc()

    def momentum_plus(self, q0, z):
        return self.Mdiag * (z - q0) / self.h - 0.5 * self.h * self._force(z)

    def explicit(self):
        # The residual is affine in q_{n+1} with the constant diagonal Jacobian -M/h:
        # one solve is exact (Stormer-Verlet).  No Newton iteration is needed.
        return True


def make_scheme(model, h, name=None):
    name = name or model.scheme
    return {"midpoint": Midpoint, "trapezoidal": Trapezoidal}[name](model, h)


@dataclass
class State:
    """Everything a restart needs: level n, (q_n, p_n), the last half-level algebraic unknowns
    and the last step velocity (used only by the predictor)."""

    n: int
    t: float
    q: np.ndarray
    p: np.ndarray
    lam: np.ndarray
    v: np.ndarray
    q_prev: np.ndarray | None = None  #: q_{n-1}, to evaluate the last step's energy

    def copy(self):
        return State(self.n, self.t, self.q.copy(), self.p.copy(), self.lam.copy(), self.v.copy(),
                     None if self.q_prev is None else self.q_prev.copy())


@dataclass
class StepStats:
    iterations: int = 0
    n_residual: int = 0
    n_jacobian: int = 0
    total_iterations: int = 0
    total_jacobians: int = 0


class Simulation:
    """Public step API: ``sim.step()`` advances one time step; ``sim.state`` is the current level."""

    def __init__(self, model, h=None, scheme=None, tol=None, max_iter=None, state=None):
        tcfg = model.scene.time
        self.model = model
        self.h = float(h if h is not None else tcfg.step)
        self.scheme = make_scheme(model, self.h, scheme)
        self.tol = tol if tol is not None else tcfg.newton_tol
        self.max_iter = max_iter if max_iter is not None else tcfg.max_iterations
        self.state = state if state is not None else State(0, 0.0, model.q_init.copy(), model.p_init.copy(),
                                                           model.lam_init.copy(), model.v_init.copy())
        self.stats = StepStats()
        self._factor = None
        self.scale = self._scales()
        #: the unknowns are displacements from c0: the residual's round-off is relative to |c0 + z|
        self.offset = np.asarray(abs(model.B).T @ np.abs(model.c0)).ravel()

    def _scales(self):
        m = self.model
        sc = np.ones(m.nz)
        for name, sl in m.layout.items():
            if name == "s":
                sc[sl] = m.L / m.M
            elif name == "R":
                sc[sl] = m.R0
            elif name == "mu":
                # the multiplier is a pressure; its round-off is set by the wall's stiffness
                w = m.wall
                p_wall = w.stiffness if w.law == "tube-law" else w.beta2 * m.R0 / (2 * np.pi)
                sc[sl] = max(abs(m.scene.fluid.pressure), p_wall)
        return sc

    def invalidate_jacobian(self):
        """Forget the reused factorisation (done at checkpoints so a restart repeats the same arithmetic)."""
        self._factor = None

    def _where(self, n):
        return f"step {n} (t = {n * self.h:.6g} s)"

    def _folded(self, n, problem, what):
        k, text = problem
        return SolverError(f"{self._where(n)}: {text} {what}: the step is too large for this motion; "
                           "try a smaller time.step", step=n, time=n * self.h)

    def step(self):
        st = self.state
        m = self.model
        nq = m.nq
        n1 = st.n + 1
        z0 = np.concatenate([st.q + self.h * st.v, st.lam])
        sch = self.scheme
        if sch.explicit():
            z = st.q + self.h * (st.p - 0.5 * self.h * sch._force(st.q)) / sch.Mdiag
            iters, nres, njac = 1, 1, 0
        else:
            res = newton(lambda z: sch.residual(st.q, st.p, z), lambda z: sch.jacobian(st.q, z), z0, self.scale,
                         self.tol, self.max_iter, self._factor, offset=self.offset)
            if not res.converged:
                self._factor = None
                # an iterate outside the lattice's domain gives a non-finite residual or Jacobian: name the label
                problem = m.label_problem(self._step_config(st.q, res.z))
                if problem is not None:
                    where = f"in Newton iterate {res.iterations}" if res.iterations else "in the predictor (last velocity extrapolated)"
                    raise self._folded(n1, problem, where)
                raise SolverError(
                    f"Newton failed at {self._where(n1)}: {res.message}; "
                    f"scaled update {res.error:.3g}, contraction rate {res.rate:.3g} after {res.iterations} iterations; "
                    "try a smaller time.step", step=n1, time=n1 * self.h, residual=res.error, rate=res.rate)
            self._factor = res.factor
            z, iters, nres, njac = res.z, res.iterations, res.n_residual, res.n_jacobian
        q1, lam = z[:nq], z[nq:]
        problem = m.label_problem(m.config(np.concatenate([q1, lam])))
        if problem is not None:
            self._factor = None
            raise self._folded(n1, problem, "at the new time level")
        p1 = sch.momentum_plus(st.q, z)
        v = (q1 - st.q) / self.h
        self.state = State(n1, n1 * self.h, q1.copy(), p1, lam.copy(), v, st.q.copy())
        s = self.stats
        s.iterations, s.n_residual, s.n_jacobian = iters, nres, njac
        s.total_iterations += iters
        s.total_jacobians += njac
        return self.state

    def _step_config(self, q0, z):
        """The configuration the step's residual evaluates at z (the midpoint, or the new level)."""
        nq = self.model.nq
        if isinstance(self.scheme, Midpoint):
            return self.model.config(np.concatenate([0.5 * (q0 + z[:nq]), z[nq:]]))
        return self.model.config(z)

    # -- monitors -------------------------------------------------------------

    def monitors(self):
        """Invariants and energies at the current level.

        Energy: without algebraic unknowns, H(q_n, p_n) = 1/2 p M^-1 p + U(q_n) at the level (exactly
        conserved by the midpoint rule on linear problems, whatever h); with them (quasistatic wall,
        incompressible fluid) the energy of the step that ended here, 1/2 v M v + U(midpoint), because
        their half-level unknowns have no value at a level.  Record 0: the initial data.
        """
        m, st = self.model, self.state
        out = {}
        if m.nlam == 0 or st.q_prev is None:
            pot = m.energies(m.config(np.concatenate([st.q, st.lam])))
            v = st.p / np.where(m.mass > 0, m.mass, 1.0) if st.q_prev is not None else st.v
        else:
            pot = self.scheme.step_energies(st.q_prev, np.concatenate([st.q, st.lam]))
            v = st.v
        kin = 0.5 * m.mass * v * v
        kf = float(np.sum(kin[m.layout["s"]])) if "s" in m.layout else 0.0
        kw = float(np.sum(kin[m.layout["R"]])) if m.wall_dynamic else 0.0
        out["kinetic_energy"] = kf + kw
        out["energy_fluid_kinetic"] = kf
        out["energy_wall_kinetic"] = kw
        for k, val in pot.items():
            out[f"energy_{k}"] = val
        out["energy"] = out["kinetic_energy"] + sum(pot.values())
        # the mass the state holds: density field times the parcel volumes of the configuration (for an
        # incompressible fluid at the step's midpoint, where its volume constraint is imposed)
        out["mass"] = m.fluid_mass(self._mass_config()) if m.has_fluid else 0.0
        mom = np.zeros(3)
        if "s" in m.layout:
            mom[0] = float(np.sum(st.p[m.layout["s"]]))
        out["linear_momentum"] = mom
        # every fluid label moves along the x axis through the origin: r x p = 0
        out["angular_momentum"] = np.zeros(3)
        out["newton_iterations"] = self.stats.iterations
        if m.has_fluid:
            out["entropy"] = float(np.sum(m.m * m.S))
            if m.incompressible:
                out["constraint_residual"] = float(np.max(np.abs(m.volumes(self._mass_config()) / m.V0 - 1.0)))
        return out

    def _mass_config(self):
        """The level's configuration, or the last step's midpoint for an incompressible fluid."""
        m, st = self.model, self.state
        q = st.q if not m.incompressible or st.q_prev is None else 0.5 * (st.q + st.q_prev)
        return m.config(np.concatenate([q, st.lam]))

    def fields(self):
        """Field values at the current level, keyed by HDF5 path under /fields."""
        m, st = self.model, self.state
        cfg = m.config(np.concatenate([st.q, st.lam]))
        out = {}
        if m.has_fluid:
            rho, p, u = m.fluid_fields(cfg, st.p)
            out["fluid/s"] = cfg.s.copy()
            out["fluid/density"] = rho
            out["fluid/pressure"] = p
            out["fluid/velocity"] = u
            out["fluid/entropy"] = m.S.copy()
        if m.has_wall:
            out["wall/R"] = m.full_radius(cfg)
            if m.wall_dynamic:
                vR = st.v[m.layout["R"]]
                out["wall/velocity"] = np.append(vR, vR[0]) if m.periodic else vR.copy()
        return out
