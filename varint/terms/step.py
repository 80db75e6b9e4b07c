"""The terms of one step's discrete Lagrangian L_d(q_n, q_{n+1}, lam), kinetic ones included.

The stepper (:mod:`varint.run.simulation`) solves the position-momentum discrete Euler-Lagrange equations of
L_d = sum of these terms (docs/theory.md §4, §9):

    p_n + D1 L_d + f^- = 0,    D_lam L_d = 0,    p_{n+1} = D2 L_d + f^+.

Each term reads the two levels of a step (:class:`StepPoint`) and adds its value, its exact D1 / D_lam
(level n and algebraic unknowns) or D2 (level n+1) into a :class:`Derivatives`, and its block of the
Newton Jacobian d(residual)/dz, in the step unknowns z of :class:`varint.model.model.Model`.  Derivatives are
taken in each block's own variations: plain for the tube's labels, radii and multipliers; for the rod,
dr (spatial) and sigma (Lambda -> Lambda cay(sigma), body) per node.

Terms know no stepper and no assembly: the model lists them, the stepper sums them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numba import njit

from ..lattice.centreline import k_centreline_weights, k_stencil_point

__all__ = ["StepPoint", "Derivatives", "TubeKinetic", "TubeMidpointPotential", "TubeTrapezoidalPotential", "RodElements",
           "RodConstraint", "CoupledFluid"]


@dataclass
class StepPoint:
    """Both levels of a step, in each part's own coordinates (``None`` for an absent part)."""

    h: float
    q0: np.ndarray | None = None  #: tube inertial unknowns at level n
    q1: np.ndarray | None = None  #: ... at level n+1
    lam: np.ndarray | None = None  #: tube algebraic unknowns (half level)
    Lam_n: np.ndarray | None = None  #: rod frames at level n (N+1, 3, 3)
    r_n: np.ndarray | None = None  #: rod positions at level n (relative to the floating origin)
    xi: np.ndarray | None = None  #: cay^-1(Lambda_n^T Lambda_{n+1}) per node
    r_1: np.ndarray | None = None  #: rod positions at level n+1
    Lam_1: np.ndarray | None = None  #: rod frames at level n+1, re-orthonormalised (set when f^+ is asked)
    rod_lam: np.ndarray | None = None  #: the inextensible rod's multipliers (N, 3), at level n (SHAKE)
    #: the rod's increments r_1 - r_n = Lambda_n b, unrounded by |r| (the rod's kinetic rows read these, docs/theory.md
    #: §9, "Momenta to round-off"); None: the element kernel forms r_1 - r_n from the absolute positions
    dr: np.ndarray | None = None


class Derivatives:
    """D1 (with D_lam) or D2 of L_d, per part."""

    def __init__(self, model):
        t, r = model.tube, model.rod
        self.tube_q = np.zeros(t.nq if t is not None else 0)
        self.tube_lam = np.zeros(t.nlam if t is not None else 0)
        self.rod = np.zeros((r.N + 1, 6)) if r is not None else None
        self.rod_lam = np.zeros((r.N, 3)) if r is not None and r.constrained else None


def _embed(block, offset, nz):
    """A square sparse block placed at (offset, offset) of an (nz, nz) matrix."""
    if offset == 0 and block.shape == (nz, nz):  # the only part: no copy
        return sp.csc_matrix(block)
    block = sp.coo_matrix(block)
    return sp.csc_matrix((block.data, (block.row + offset, block.col + offset)), shape=(nz, nz))


def _rod_derivative(rod, pt, level, elastic=True):
    """The rod's D1 (level 0) or D2 (level 1) at the step point, from its increments ``pt.dr`` when the point has them
    (each element centred on its first node with its exact increments: varint.terms.rod.k_rod_gradient), else from
    r_1 - r_n.  ``elastic=False``: the kinetic, weight and tip-force pieces only (the stiffnesses set to zero), the
    closed-form momentum balances' rod part."""
    return rod.gradients(pt.h, pt.Lam_n, pt.r_n, pt.xi, pt.r_1, levels=(level, level + 1), dr=pt.dr,
                         elastic=elastic)[level]


@njit(cache=True)
def _k_kinetic_increments(s0, s1, r0, dr, mbar, h, ds, periodic, period, rod0, rod1, g0, g1):
    """:meth:`CoupledFluid._kinetic_increments`: the rows -mbar/h N_a(s^n) D, +mbar/h N_a(s^{n+1}) D (into rod0, rod1,
    translational columns) and -mbar/h D . X'(s^n), +mbar/h D . X'(s^{n+1}) (g0, g1) with
    D = sum_a N_a(s^{n+1}) dr_a + [sum_a N_a(s^{n+1}) (r_a^n - c) - sum_a N_a(s^n) (r_a^n - c)], c the first node of the
    label's level-n stencil (the period added past the end of a periodic tube, as ``_centreline_points``).  The bracket
    does not read dr: D moves with dr to eps |D|, and is exact for a label that does not slide."""
    n = r0.shape[0]
    m = s0.shape[0]
    nodes0 = np.empty((m, 4), np.int64)
    nodes1 = np.empty((m, 4), np.int64)
    N0, dN0, d2N = np.empty((m, 4)), np.empty((m, 4)), np.empty((m, 4))
    N1, dN1 = np.empty((m, 4)), np.empty((m, 4))
    k_centreline_weights(s0, n, ds, periodic, nodes0, N0, dN0, d2N)
    k_centreline_weights(s1, n, ds, periodic, nodes1, N1, dN1, d2N)
    D = np.empty(3)
    c = np.empty(3)
    r1 = r0 + dr
    for q in range(m):
        e0 = int(math.floor(s0[q] / ds))
        e1 = int(math.floor(s1[q] / ds))
        for d in range(3):
            c[d] = k_stencil_point(r0, nodes0[q, 1], e0, 1, n, periodic, period, d)
        for d in range(3):
            inc = 0.0
            b1 = 0.0
            b0 = 0.0
            for i in range(4):
                inc += N1[q, i] * dr[nodes1[q, i], d]
                b1 += N1[q, i] * (k_stencil_point(r0, nodes1[q, i], e1, i, n, periodic, period, d) - c[d])
                b0 += N0[q, i] * (k_stencil_point(r0, nodes0[q, i], e0, i, n, periodic, period, d) - c[d])
            D[d] = inc + (b1 - b0)
        cm = mbar[q] / h
        x0 = 0.0
        x1 = 0.0
        for d in range(3):
            t0 = 0.0
            t1 = 0.0
            for i in range(4):
                t0 += dN0[q, i] * k_stencil_point(r0, nodes0[q, i], e0, i, n, periodic, period, d)
                t1 += dN1[q, i] * k_stencil_point(r1, nodes1[q, i], e1, i, n, periodic, period, d)
                rod0[nodes0[q, i], d] -= cm * N0[q, i] * D[d]
                rod1[nodes1[q, i], d] += cm * N1[q, i] * D[d]
            x0 += D[d] * t0
            x1 += D[d] * t1
        g0[q] = -cm * x0
        g1[q] = cm * x1


class TubeKinetic:
    """h 1/2 v.M.v, v = (q1 - q0)/h, with the tube's constant diagonal mass (labels and dynamic radii)."""

    name = "tube_kinetic"

    def __init__(self, tube, offset, nz):
        self.tube, self.offset, self.nz = tube, offset, nz

    @property
    def mass(self):
        return self.tube.mass

    def value(self, pt):
        v = (pt.q1 - pt.q0) / pt.h
        return pt.h * 0.5 * float(np.dot(self.mass * v, v))

    def add(self, pt, d, level):
        mv = self.mass * (pt.q1 - pt.q0) / pt.h
        d.tube_q += -mv if level == 0 else mv

    def jacobian(self, pt):
        t = self.tube
        diag = np.concatenate([-self.mass / pt.h, np.zeros(t.nlam)])
        return _embed(sp.diags(diag), self.offset, self.nz)

    def constant_diagonal_jacobian(self):
        return True


class TubeMidpointPotential:
    """-h U(config((q0 + q1)/2, lam)): the tube's potential terms (varint.terms.tube_potential) at the step's midpoint."""

    name = "tube_potential"
    order = 2  #: global order in h of the scheme it makes (symmetric one-stage quadrature)

    def __init__(self, tube, offset, nz):
        self.tube, self.offset, self.nz = tube, offset, nz
        self.Bq = tube.B[:, :tube.nq]
        self.Bl = tube.B[:, tube.nq:]
        # transposes built once (a CSR transpose per residual was a fifth of a small step)
        self.BqT, self.BlT = self.Bq.T.tocsr(), self.Bl.T.tocsr()

    def config(self, pt):
        return self.tube.config(np.concatenate([0.5 * (pt.q0 + pt.q1), pt.lam]))

    def value(self, pt):
        return -pt.h * self.tube.potential(self.config(pt), self.tube.midpoint_terms)

    def add(self, pt, d, level):
        g = self.tube.gradient(self.config(pt), self.tube.midpoint_terms)
        d.tube_q -= 0.5 * pt.h * (self.BqT @ g)
        if level == 0:
            d.tube_lam -= pt.h * (self.BlT @ g)

    def jacobian(self, pt):
        H = self.tube.hessian(self.config(pt), self.tube.midpoint_terms)
        C = sp.hstack([0.5 * self.Bq, self.Bl]).tocsr()
        return _embed(-pt.h * (C.T @ H @ C), self.offset, self.nz)

    def constant_diagonal_jacobian(self):
        return False

    def energies(self, pt):
        """Each potential term's value at the step's midpoint (the step-energy monitor)."""
        return self.tube.energies(self.config(pt))


class TubeTrapezoidalPotential:
    """-h [U(q0) + U(q1)]/2 (Stormer-Verlet; only without algebraic unknowns)."""

    name = "tube_potential"
    order = 2  #: global order in h (Stormer-Verlet)

    def __init__(self, tube, offset, nz):
        if tube.nlam:
            raise ValueError("the trapezoidal scheme needs every unknown to carry inertia")
        self.tube, self.offset, self.nz = tube, offset, nz
        self.Bq = tube.B[:, :tube.nq]
        self.BqT = self.Bq.T.tocsr()

    def _U(self, q):
        return self.tube.potential(self.tube.config(q))

    def value(self, pt):
        return -0.5 * pt.h * (self._U(pt.q0) + self._U(pt.q1))

    def add(self, pt, d, level):
        q = pt.q0 if level == 0 else pt.q1
        d.tube_q -= 0.5 * pt.h * (self.BqT @ self.tube.gradient(self.tube.config(q)))

    def jacobian(self, pt):
        # D1 reads level n only: the step residual is affine in q_{n+1} (explicit Stormer-Verlet)
        return sp.csc_matrix((self.nz, self.nz))

    def constant_diagonal_jacobian(self):
        return True


class RodElements:
    """The rod's element kernels (varint.terms.rod ``k_element``): kinetic, elastic, gravity and dead tip force.

    One term because one element kernel computes them together, exactly (docs/theory.md §9); the
    declarations of its pieces are :meth:`varint.terms.rod.RodPart.declarations`.  Its Newton block has the
    translational rows in the level-n body frame of their node and the columns in (b, xi), the chart
    of the rod blocks (:class:`varint.model.model.Model`).
    """

    name = "rod"
    order = 2

    def __init__(self, rod, offset, nz):
        self.rod, self.offset, self.nz = rod, offset, nz

    def value(self, pt):
        return self.rod.gradients(pt.h, pt.Lam_n, pt.r_n, pt.xi, pt.r_1)[2]

    def add(self, pt, d, level):
        d.rod += _rod_derivative(self.rod, pt, level)

    def rigid_part(self, pt, d):
        """Add the level-n pieces of D1 that the rigid motions do not annihilate (kinetic, weight, tip force; the
        elastic forces' sums vanish identically, docs/theory.md §9, "Momenta to round-off") into ``d``; return the
        point masses (m, x_n, x_{n+1}) and the rotational inertias (I (N+1, 3), Lambda_n) of the polish's 6x6 system."""
        rod = self.rod
        d.rod += _rod_derivative(rod, pt, 0, elastic=False)
        dr = pt.dr if pt.dr is not None else pt.r_1 - pt.r_n
        return (rod.node_mass, pt.r_n, pt.r_n + dr), (rod.node_inertia, pt.Lam_n)

    def jacobian(self, pt):
        return _embed(self.rod.step_jacobian(pt.h, pt.Lam_n, pt.r_n, pt.xi, pt.r_1), self.offset, self.nz)

    def constant_diagonal_jacobian(self):
        return False


class RodConstraint:
    """The inextensible, unshearable rod (varint.terms.rod_constraint), its constraint held at the levels (SHAKE,
    docs/theory.md §9a): the step's term is -h sum_e ds lambda_e^n . (Gamma_e(q_n) - chi), whose force acts at the
    known level n, and the step's constraint rows are -h ds (Gamma_e(q_{n+1}) - chi), the derivative in lambda^{n+1}
    of the next step's term: Gamma = chi at every level to the solver tolerance.  (The earlier midpoint form,
    Gammabar = chi, steps the same trajectory; its half-level multipliers were free to alternate, which never moved
    the rod: docs/theory.md §9a.)

    Its Newton block: the multipliers' columns (the level-n force is linear in lambda and independent of q_{n+1})
    and the constraint rows, in the rod's chart (b, xi) as RodElements'.
    """

    name = "inextensibility"
    order = 2

    def __init__(self, model):
        self.model, self.rod = model, model.rod
        rod = self.rod
        idx = rod.node_index()
        idx[idx >= 0] += model.rod_z.start
        e = np.arange(rod.N)[:, None]
        loc = np.arange(12)[None, :]
        self._elem_idx = idx[(e + loc // 6), loc % 6]  # (N, 12) step-unknown index of each element entry, -1 off the mask
        lam_idx = np.full((rod.N, 3), -1)
        lam_idx[:, :rod.ncomp] = (model.rod_lam_z.start + np.arange(rod.nlam)).reshape(rod.N, rod.ncomp)
        self._lam_idx = lam_idx

    def _lam1(self, pt):
        from ..lattice.lie import cay

        return pt.Lam_n @ cay(pt.xi)

    def _step(self, pt):
        from .rod_constraint import level_constraint_step

        return level_constraint_step(pt.h, self.rod.ds, pt.Lam_n, pt.r_n, self._lam1(pt), pt.r_1, pt.rod_lam,
                                     self.rod.ncomp)

    def value(self, pt):
        return self._step(pt)[0]

    def add(self, pt, d, level):
        if level == 0:  # the force at level n and the rows at level n+1; nothing in D2
            _, F, row = self._step(pt)
            d.rod += F
            d.rod_lam += row

    def jacobian(self, pt):
        from .rod_constraint import constraint_blocks

        rod = self.rod
        _, lam_blocks, row_blocks = constraint_blocks(pt.h, rod.ds, pt.Lam_n, pt.r_n, pt.xi, pt.r_1, pt.rod_lam,
                                                      rod.ncomp, rod.column_mask, at_levels=True)
        E, L = self._elem_idx, self._lam_idx
        rows = [np.broadcast_to(E[:, :, None], lam_blocks.shape), np.broadcast_to(L[:, :, None], row_blocks.shape)]
        cols = [np.broadcast_to(L[:, None, :], lam_blocks.shape), np.broadcast_to(E[:, None, :], row_blocks.shape)]
        vals = [lam_blocks, row_blocks]
        r = np.concatenate([x.ravel() for x in rows])
        c = np.concatenate([x.ravel() for x in cols])
        v = np.concatenate([x.ravel() for x in vals])
        keep = (r >= 0) & (c >= 0)
        nz = self.model.nz
        return sp.csc_matrix((v[keep], (r[keep], c[keep])), shape=(nz, nz))

    def constant_diagonal_jacobian(self):
        return False


class CoupledFluid:
    """The fluid on the moving centreline (docs/theory.md §10): its kinetic energy in inertial form and its
    midpoint potential (internal energy or incompressibility, p_ext on the tube's volume, gravity), which
    read the rod's positions and frames and the tube's labels, radii and multipliers.

    The kernels (:mod:`varint.terms.coupled`) return the level gradients per node [dr, sigma] and per
    label/radius of the full configuration, and the Newton block in their own ordering
    [rod 6/node | s (M+1) | R (nR) | mu (M)].  ``P`` maps that ordering to the model's step unknowns: the
    rod's entries on the support mask, the tube's through its selection B (end labels and rigid radii are
    data), with weight 2 on a quasistatic radius, which is the half-level value of both levels
    (d/dR_{n+1/2} = d/dR^n + d/dR^{n+1}: twice either, the potential reads Rbar only).

    An incompressible liquid in a rigid or dynamic wall holds its volumes at the levels (docs/theory.md §10.12):
    the step's L_d is the midpoint one without the multiplier term plus h mu_n . (V(q_n) - V0), and the step
    solves (q_{n+1}, mu_n) from p_n + D1 L_d + h G(q_n)^T mu_n = 0 and h (V(q_{n+1}) - V0) = 0 (SHAKE), so the
    midpoint's alternating mode about the constraint surface does not exist.  In a quasistatic wall (radii at
    half levels) the liquid keeps the midpoint constraint.
    """

    name = "fluid"
    order = 2

    def __init__(self, model):
        from .coupled import FluidPotential, newton_offsets

        t, rod = model.tube, model.rod
        self.model, self.t, self.rod = model, t, rod
        # a periodic tube's kernels read nodes 0..N-1 and wrap with the period (node N is node 0's image)
        self.n_nodes = n_nodes = rod.N if rod.periodic else rod.N + 1
        #: open ends (docs/theory.md §13.1): the kernels read the centreline extended beyond the ends
        #: (varint.terms.open_ends.CoupledExtension), the liquid's multipliers are gauge pressures (p_ext = 0 here)
        self.ext = t.ext if t.open else None
        self.fp = FluidPotential(ds=t.ds, m=t.m, mbar=t.label_mass_all, eos=t.eos, S=t.S if t.eos is not None else None,
                                 V0=t.V0 if t.incompressible else None, p_ext=0.0 if t.open else t.p_ext,
                                 g=np.array(rod.g, dtype=float),
                                 periodic=rod.periodic, period=rod.period if rod.periodic else None)
        off, n = newton_offsets(n_nodes, t.M + 1, t.nR, t.M if t.incompressible else 0)
        self.n_order = n
        self.R_weight = 2.0 if t.has_wall and not t.wall_dynamic else 1.0
        rows, cols, vals = [], [], []
        idx = rod.node_index()[:n_nodes]
        j, d = np.nonzero(idx >= 0)
        rows.append(6 * j + d)
        cols.append(model.rod_z.start + idx[j, d])
        vals.append(np.ones(len(j)))
        B = t.B.tocoo()
        i = t.index
        helper_row = np.empty(t.nconfig, np.int64)
        helper_row[:i["R"]] = off["s"] + np.arange(i["R"])
        helper_row[i["R"]:i["R"] + t.nR] = off["R"] + np.arange(t.nR)
        helper_row[i["mu"]:t.nconfig] = off["mu"] + np.arange(t.nconfig - i["mu"])
        w = np.ones(len(B.row))
        w[(B.row >= i["R"]) & (B.row < i["R"] + t.nR)] = self.R_weight
        rows.append(helper_row[B.row])
        cols.append(model.tube_z.start + B.col)
        vals.append(w)
        self.P = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, model.nz))
        # every kernel index maps to at most one step unknown (B is a selection): J = P^T J_kernel P is then a
        # relabelling of the kernel's triplets, done by indexing instead of two sparse products
        P = self.P.tocoo()
        assert np.all(np.bincount(P.row, minlength=n) <= 1)
        self.z_of = np.full(n, -1)
        self.z_of[P.row] = P.col
        self.w_of = np.zeros(n)
        self.w_of[P.row] = P.data
        self.BT = t.B.T.tocsr()
        #: SHAKE: the liquid's volumes held at the levels (theory §10.12); a quasistatic wall keeps the midpoint's
        self.level_constraint = bool(t.incompressible and not (t.has_wall and not t.wall_dynamic))
        if self.level_constraint:
            import dataclasses

            self.fp0 = dataclasses.replace(self.fp, p_ext=0.0, g=np.zeros(3))
            n_k = n_nodes if self.ext is None else self.ext.n_ext
            self.off0, self.n0 = newton_offsets(n_k, t.M + 1, t.nR if self.ext is None else n_k, t.M)

    def levels(self, pt):
        """(s0, R0, s1, R1, mu, Lam1) of the step: the tube's full configurations at both levels."""
        from ..lattice.lie import cay

        t = self.t
        c0 = t.config(np.concatenate([pt.q0, pt.lam]))
        c1 = t.config(np.concatenate([pt.q1, pt.lam]))
        if self.ext is not None and t.n_fixed:
            # the inlet's piston: the stepper holds its step-midpoint position in c0 while it solves; its two levels are
            # half a step's travel either side (its kinetic energy moves with the rod, docs/theory.md §13.1)
            c0.s[0] -= 0.5 * pt.h * t.U_in
            c1.s[0] += 0.5 * pt.h * t.U_in
        return c0.s, c0.R, c1.s, c1.R, c0.mu, pt.Lam_n @ cay(pt.xi)

    def _valid(self, s):
        """Labels ordered and inside the tube (the kernels extrapolate outside it: a Newton iterate there could
        converge to a spurious root; NaN makes Newton back off or fail cleanly instead, as on the fixed tube)."""
        from ..lattice.parcels import label_problem

        t = self.t
        if self.ext is not None:
            return label_problem(s + self.ext.shift, self.ext.n_ext, t.ds, False) is None
        return label_problem(s, t.nR, t.ds, t.periodic) is None

    def _extended(self, pt, s0, R0, s1, R1, Lam1):
        """The step's data on the extended lattice of open ends: labels shifted, ghost nodes and frames."""
        e = self.ext
        return (s0 + e.shift, e.positions(pt.r_n), e.frames(pt.Lam_n), e.pad(R0), s1 + e.shift, e.positions(pt.r_1),
                e.frames(Lam1), e.pad(R1))

    def _parts(self, pt, newton=False, kinetic=True, lv=None):
        """(potential, kinetic) StepTerms of the kernels; ``kinetic=False``: the kinetic one is None (the caller forms
        its rows from the increments, :meth:`_kinetic_increments`); ``lv``: :meth:`levels`, when the caller has them."""
        from .coupled import fluid_kinetic_chart, fluid_potential_step

        s0, R0, s1, R1, mu, Lam1 = lv if lv is not None else self.levels(pt)
        if self.level_constraint:  # the multipliers act at the levels (_level_volumes), not at the midpoint
            mu = np.zeros_like(mu)
        if not (self._valid(s0) and self._valid(s1)):
            return None, None
        k, fp = self.n_nodes, self.fp
        if self.ext is not None:
            s0e, r0e, L0e, R0e, s1e, r1e, L1e, R1e = self._extended(pt, s0, R0, s1, R1, Lam1)
            pot = fluid_potential_step(fp, pt.h, s0e, r0e, L0e, R0e, s1e, r1e, L1e, R1e, mu=mu, newton=newton)
            kin = fluid_kinetic_chart(s0e, r0e, L0e, s1e, r1e, fp.mbar, pt.h, self.t.ds, False, None, newton=newton)
            return pot, kin
        pot = fluid_potential_step(fp, pt.h, s0, pt.r_n[:k], pt.Lam_n[:k], R0, s1, pt.r_1[:k], Lam1[:k], R1, mu=mu,
                                   newton=newton)
        if not kinetic:
            return pot, None
        kin = fluid_kinetic_chart(s0, pt.r_n[:k], pt.Lam_n[:k], s1, pt.r_1[:k], fp.mbar, pt.h, self.t.ds, fp.periodic,
                                  fp.period, newton=newton)
        return pot, kin

    def _level_volumes(self, pt, hessian):
        """fluid_potential_static of U_mu = -mu_n . (V - V0) (no p_ext, no gravity) at level n and at level n+1, on
        the kernels' lattice (extended for open ends): U, its gradient and Hessian in the chart r + dr,
        Lambda cay(sigma), s, R, mu; d/dmu is -(V - V0)."""
        from .coupled import fluid_potential_static

        s0, R0, s1, R1, mu, Lam1 = self.levels(pt)
        if self.ext is not None:
            s0e, r0e, L0e, R0e, s1e, r1e, L1e, R1e = self._extended(pt, s0, R0, s1, R1, Lam1)
            return (fluid_potential_static(self.fp0, s0e, r0e, L0e, R0e, mu=mu, hessian=hessian),
                    fluid_potential_static(self.fp0, s1e, r1e, L1e, R1e, mu=mu, hessian=hessian))
        k = self.n_nodes
        return (fluid_potential_static(self.fp0, s0, pt.r_n[:k], pt.Lam_n[:k], R0, mu=mu, hessian=hessian),
                fluid_potential_static(self.fp0, s1, pt.r_1[:k], Lam1[:k], R1, mu=mu, hessian=hessian))

    def _kinetic_increments(self, pt, s0, s1):
        """The fluid kinetic term's level gradients (rod (n, 6), labels) at levels n and n+1, as
        ``fluid_kinetic_chart``'s (grad = mbar/h D . dD/d(level), D = X_k^{n+1} - X_k^n), with D formed from the rod's
        increments instead of from absolute centreline points: per label, with positions relative to its element's first
        node c at level n, D = sum_a N_a(s^{n+1}) dr_a + [sum_a N_a(s^{n+1}) (r_a^n - c) - sum_a N_a(s^n) (r_a^n - c)].
        The kernel's D is rounded to eps |X| (over h: a velocity quantum that Newton and the rigid polish cannot go
        below, 1e-14 of the momentum per label and step for a liquid at h = 1 ms); this one moves with dr to eps |D|
        (docs/theory.md §10.6, "Momenta to round-off").  A closed tube (not open ends)."""
        from .coupled import _period_vector

        k, fp = self.n_nodes, self.fp
        rod0, rod1 = np.zeros((k, 6)), np.zeros((k, 6))
        g0, g1 = np.empty(len(s0)), np.empty(len(s0))
        _k_kinetic_increments(np.ascontiguousarray(s0, dtype=np.float64), np.ascontiguousarray(s1, dtype=np.float64),
                              np.ascontiguousarray(pt.r_n[:k]), np.ascontiguousarray(pt.dr[:k]),
                              np.ascontiguousarray(fp.mbar, dtype=np.float64), float(pt.h), float(self.t.ds),
                              bool(fp.periodic), _period_vector(k, self.t.ds, fp.period), rod0, rod1, g0, g1)
        return (rod0, g0), (rod1, g1)

    def value(self, pt):
        pot, kin = self._parts(pt)
        if pot is None:
            return np.nan
        if self.level_constraint:  # + h mu_n . (V(q_n) - V0) = -h U_mu(q_n)
            return pot.L + kin.L - pt.h * self._level_volumes(pt, False)[0][0]
        return pot.L + kin.L

    def kinetic_value(self, pt):
        """The fluid kinetic part of the step's L_d (h times the step's fluid kinetic energy)."""
        from .coupled import fluid_kinetic_step

        s0, R0, s1, R1, _, Lam1 = self.levels(pt)
        if not (self._valid(s0) and self._valid(s1)):
            return np.nan
        k, fp = self.n_nodes, self.fp
        if self.ext is not None:
            s0e, r0e, _, _, s1e, r1e, _, _ = self._extended(pt, s0, R0, s1, R1, Lam1)
            return fluid_kinetic_step(s0e, r0e, s1e, r1e, fp.mbar, pt.h, self.t.ds, False, None, hessian=False)[0]
        return fluid_kinetic_step(s0, pt.r_n[:k], s1, pt.r_1[:k], fp.mbar, pt.h, self.t.ds, fp.periodic, fp.period,
                                  hessian=False)[0]

    def add(self, pt, d, level):
        t = self.t
        inc = self.ext is None and pt.dr is not None  # the kinetic rows from the increments (_kinetic_increments)
        lv = self.levels(pt)
        pot, kin = self._parts(pt, kinetic=not inc, lv=lv)
        if pot is None:
            d.rod += np.nan
            d.tube_q += np.nan
            d.tube_lam += np.nan
            return
        Dp = pot.D1 if level == 0 else pot.D2
        if inc:
            k_rod, k_s = self._kinetic_increments(pt, lv[0], lv[2])[level]
        else:
            Dk = kin.D1 if level == 0 else kin.D2
            k_rod, k_s = Dk.rod, Dk.s
        gc = np.zeros(t.nconfig)
        i = t.index
        gc[:i["R"]] = Dp.s + k_s
        if self.ext is not None:
            d.rod[:self.n_nodes] += self.ext.fold_gradient(Dp.rod + Dk.rod)
            gc[i["R"]:i["R"] + t.nR] = self.R_weight * self.ext.fold_radii(Dp.R)
        else:
            d.rod[:self.n_nodes] += Dp.rod + k_rod
            gc[i["R"]:i["R"] + t.nR] = self.R_weight * Dp.R
        if level == 0 and t.incompressible:
            gc[i["mu"]:] = pot.Dmu
        if level == 0 and self.level_constraint:
            # h G(q_n)^T mu_n = -h dU_mu(q_n), and the constraint row h (V(q_{n+1}) - V0) = -h dU_mu(q_{n+1})/dmu
            (_, g0, _), (_, g1, _) = self._level_volumes(pt, False)
            o = self.off0
            rod_f, R_f = -pt.h * g0[:o["s"]].reshape(-1, 6), -pt.h * g0[o["R"]:o["mu"]]
            if self.ext is not None:
                rod_f, R_f = self.ext.fold_gradient(rod_f), self.ext.fold_radii(R_f)
            d.rod[:self.n_nodes] += rod_f
            gc[:i["R"]] -= pt.h * g0[o["s"]:o["R"]]
            gc[i["R"]:i["R"] + t.nR] += self.R_weight * R_f
            gc[i["mu"]:] = -pt.h * g1[o["mu"]:]
        gz = self.BT @ gc
        d.tube_q += gz[:t.nq]
        if level == 0:
            d.tube_lam += gz[t.nq:]

    def rigid_part(self, pt, d):
        """Add the level-n pieces of the fluid's D1 rod rows that the rigid motions do not annihilate into ``d``
        (docs/theory.md §10.6): the kinetic rows -mbar_k N_j(s_k^n) v_k^X (its kernel's) and the weight (h/2) mbar_k N_j(sbar_k) g; the
        internal energy's, the incompressibility's and p_ext's sums vanish identically (closed ends).  Returns the
        labels' point masses (mbar, X^n, X^{n+1}) of the polish's 6x6 system.  A closed tube only (not open ends)."""
        from ..lattice.centreline import centreline_and_weights
        from .coupled import fluid_kinetic_chart

        s0, _, s1, _, _, _ = self.levels(pt)
        k, fp = self.n_nodes, self.fp
        r1 = pt.r_n + pt.dr if pt.dr is not None else pt.r_1
        if pt.dr is not None:
            d.rod[:k] += self._kinetic_increments(pt, s0, s1)[0][0]
        else:
            d.rod[:k] += fluid_kinetic_chart(s0, pt.r_n[:k], pt.Lam_n[:k], s1, pt.r_1[:k], fp.mbar, pt.h, self.t.ds,
                                             fp.periodic, fp.period).D1.rod
        X0 = centreline_and_weights(s0, pt.r_n[:k], self.t.ds, fp.periodic, fp.period)[3]
        X1 = centreline_and_weights(s1, r1[:k], self.t.ds, fp.periodic, fp.period)[3]
        if np.any(fp.g != 0.0):
            nodes, Nw = centreline_and_weights(0.5 * (s0 + s1), pt.r_n[:k], self.t.ds, fp.periodic, fp.period)[:2]
            f = (0.5 * pt.h * fp.mbar)[:, None, None] * Nw[:, :, None] * fp.g[None, None, :]
            np.add.at(d.rod[:, :3], nodes.ravel(), f.reshape(-1, 3))
        return (fp.mbar, X0, X1), None

    def jacobian(self, pt):
        pot, kin = self._parts(pt, newton=True)
        if pot is None:
            return sp.diags(np.full(self.model.nz, np.nan)).tocsc()
        r = np.concatenate([pot.newton[0], kin.newton[0]])
        c = np.concatenate([pot.newton[1], kin.newton[1]])
        v = np.concatenate([pot.newton[2], kin.newton[2]])
        if self.level_constraint:
            r, c, v = self._level_newton(pt, r, c, v)
        if self.ext is not None:  # the extended lattice's block folded onto the real nodes: G^T J_ext G
            t = self.t
            G = self.ext.fold_matrix(pt.Lam_n, t.M + 1, t.M)
            Je = sp.csr_matrix((v, (r, c)), shape=(G.shape[0], G.shape[0]))
            Jr = (G.T @ Je @ G).tocoo()
            r, c, v = Jr.row, Jr.col, Jr.data
        zr, zc = self.z_of[r], self.z_of[c]
        keep = (zr >= 0) & (zc >= 0)
        nz = self.model.nz
        return sp.csc_matrix((v[keep] * self.w_of[r[keep]] * self.w_of[c[keep]], (zr[keep], zc[keep])), shape=(nz, nz))

    def _level_newton(self, pt, r, c, v):
        """The kernel block with its multiplier rows and columns replaced by the level constraints' (kernel ordering):
        columns d(D1)/dmu_n = -h d^2U_mu(q_n)/dq dmu (translational rows in the level-n frames), rows
        d(h (V(q_{n+1}) - V0))/d(b, xi, s, R) = -h d^2U_mu(q_{n+1})/dmu dq chained through dr = Lambda^n db,
        sigma = dcay_{-xi} dxi (the chart of docs/theory.md §10.9)."""
        from .coupled import level_chart_maps

        o, n = self.off0, self.n0
        keep = (r < o["mu"]) & (c < o["mu"])
        (_, _, H0), (_, _, H1) = self._level_volumes(pt, True)
        if self.ext is not None:
            Lam_n, xi = self.ext.frames(pt.Lam_n), pt.xi[self.ext.node_map]
        else:
            Lam_n, xi = pt.Lam_n[:self.n_nodes], pt.xi[:self.n_nodes]
        k, nq = len(Lam_n), o["mu"]
        Rot, Chart = level_chart_maps(Lam_n, xi, nq - 6 * k)
        C = (Rot @ (-pt.h * H0[:nq, nq:])).tocoo()
        Rw = ((-pt.h * H1[nq:, :nq]) @ Chart).tocoo()
        return (np.concatenate([r[keep], C.row, nq + Rw.row]), np.concatenate([c[keep], nq + C.col, Rw.col]),
                np.concatenate([v[keep], C.data, Rw.data]))

    def constant_diagonal_jacobian(self):
        return False
