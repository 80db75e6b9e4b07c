"""The variational step of every model: the position-momentum discrete Euler-Lagrange equations of L_d, with the
potential at the step's midpoint ("midpoint") or averaged over its two levels ("trapezoidal").

For a step n -> n+1 of the model's blocks (:mod:`varint.model.model`), with L_d the sum of the model's step
terms (:mod:`varint.terms.step`, kinetic ones included) and f^± the Lagrange-d'Alembert forces
(:mod:`varint.terms.forces`), the step solves (docs/theory.md §4, §9)

    p_n + D1 L_d(q_n, q_{n+1}, lam) + f^-_n = 0,      D_lam L_d(q_n, q_{n+1}, lam) = 0,

for the step unknowns z (q_{n+1} in each block's chart, and lam_{n+1/2}) by Newton, and sets
p_{n+1} = D2 L_d + f^+_n.  These residuals *are* components of the gradient of the discrete action
sum_n L_d; the test suite checks that against finite differences of :meth:`Step.discrete_lagrangian`.
The Newton Jacobian is the sum of the terms' exact blocks.

Charts (the model's layout): the tube's labels, radii and multipliers are vectors (z holds their new
values, as displacements from the reference lattice); the rod's positions are moved by the body-frame
displacement b (r_{n+1} = r_n + Lambda_n b) and its frames by the Cayley retraction
Lambda_{n+1} = Lambda_n cay(xi).  The rod's translational residual rows are rotated into the same
level-n body frames, so the Jacobian does not rotate with a tumbling rod and can be reused.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..lattice.lie import cay, cay_inv, hat
from ..terms.rod import origin_shift, pack_level, reorthonormalize, unpack_level
from ..terms.step import (CoupledFluid, Derivatives, RodConstraint, RodElements, StepPoint, TubeKinetic,
                          TubeMidpointPotential, TubeTrapezoidalPotential)

__all__ = ["Step", "make_scheme", "step_terms"]


def step_terms(model, scheme="midpoint"):
    """The terms of ``model``'s L_d with the potential quadrature ``scheme`` ("midpoint" or "trapezoidal"), kinetic
    ones included (varint/terms/step.py)."""
    terms = []
    if model.tube is not None:
        terms.append(TubeKinetic(model.tube, model.tube_z.start, model.nz))
        pot = {"midpoint": TubeMidpointPotential, "trapezoidal": TubeTrapezoidalPotential}[scheme]
        terms.append(pot(model.tube, model.tube_z.start, model.nz))
        if getattr(model.tube, "open", False) and getattr(model.tube, "level_constraint", False):
            from ..terms.open_ends import OpenLevelConstraint

            terms.append(OpenLevelConstraint(model.tube, model.tube_z.start, model.nz))
    if model.rod is not None:
        if scheme != "midpoint":
            raise ValueError(f"time.scheme: {scheme!r} is not available with [rod] (its Lie-group step is the midpoint scheme)")
        terms.append(RodElements(model.rod, model.rod_z.start, model.nz))
        if model.rod.constrained:
            terms.append(RodConstraint(model))
    if model.coupled:
        terms.append(CoupledFluid(model))
    return terms


class Step:
    """The discrete Lagrangian of one step of a model and its stationarity conditions.

    ``scheme`` names the quadrature of the potential ("midpoint", or "trapezoidal" for a tube without
    algebraic unknowns); ``order`` is the global order in h it declares (asserted by
    tests/test_convergence.py).
    """

    def __init__(self, model, h, scheme=None, forces=None):
        self.model = model
        self.h = float(h)
        self.name = scheme or model.scheme
        self.terms = step_terms(model, self.name)
        #: the non-conservative forces of the step (Lagrange-d'Alembert): the model's, or those a scheme gives
        self.forces = list(model.forces) if forces is None else list(forces)
        self.order = min(getattr(t, "order", 2) for t in self.terms)
        self._rod_flat = np.flatnonzero(model.rod.mask) if model.rod is not None else None

    # -- the two levels -------------------------------------------------------------------

    def point(self, q0, z):
        """The :class:`StepPoint` of level vector ``q0`` and step unknowns ``z``."""
        m = self.model
        pt = StepPoint(self.h)
        if m.tube is not None:
            t = m.tube
            zt = z[m.tube_z]
            pt.q0, pt.q1, pt.lam = q0[m.tube_q], zt[:t.nq], zt[t.nq:]
        if m.rod is not None:
            rod = m.rod
            Lam_n, r_n, _ = unpack_level(q0[m.rod_q], rod.N)
            u = np.zeros((rod.N + 1, 6))
            u.ravel()[self._rod_flat] = z[m.rod_z]  # (flat indices of the mask: cheaper than a boolean mask)
            if rod.periodic:
                u[rod.N] = u[0]  # the image node moves with node 0
            pt.Lam_n, pt.r_n = Lam_n, r_n
            # the increments, unrounded by |r| (docs/theory.md §10.6 "Momenta to round-off"); not with the paper's
            # measure under gravity, whose weight rho A |Gammabar_e| g . rbar reads the absolute positions
            dr = np.matmul(Lam_n, u[:, :3, None])[:, :, 0]
            pt.dr = None if (rod.paper_measure and np.any(rod.g)) else dr
            pt.r_1 = r_n + dr
            pt.xi = u[:, 3:]
            if rod.constrained:
                lam_r = np.zeros((rod.N, 3))
                lam_r[:, :rod.ncomp] = z[m.rod_lam_z].reshape(rod.N, rod.ncomp)
                pt.rod_lam = lam_r
        return pt

    def unknowns(self, q0, q1, lam=None):
        """The step unknowns z that take level ``q0`` to level ``q1`` (inverse of :meth:`retract`), with the
        half-level unknowns ``lam`` (``State.lam`` layout; default: none, or zeros)."""
        m = self.model
        if lam is None:
            lam = np.zeros(m.rod_lam.stop)
        parts = []
        if m.tube is not None:
            parts += [q1[m.tube_q], lam[m.tube_lam]]
        if m.rod is not None:
            rod = m.rod
            L0, r0, o0 = unpack_level(q0[m.rod_q], rod.N)
            L1, r1, o1 = unpack_level(q1[m.rod_q], rod.N)
            u = np.concatenate([np.einsum("nji,nj->ni", L0, (r1 + o1) - (r0 + o0)),
                                cay_inv(np.swapaxes(L0, 1, 2) @ L1)], axis=1)
            parts += [u[rod.mask], lam[m.rod_lam]]
        return np.concatenate(parts) if parts else np.empty(0)

    def velocity(self, q0, q1):
        """The predictor's data of the step from level ``q0`` to ``q1`` (``State.v``): the tube's (q1 - q0)/h, the rod's
        body-frame displacement b and xi on every node (a scheme that steps its own variables fills the state's with
        it, so that the fields' velocities are the step's)."""
        m = self.model
        parts = []
        if m.tube is not None:
            parts.append((q1[m.tube_q] - q0[m.tube_q]) / self.h)
        if m.rod is not None:
            L0, r0, o0 = unpack_level(q0[m.rod_q], m.rod.N)
            L1, r1, o1 = unpack_level(q1[m.rod_q], m.rod.N)
            parts += [np.einsum("nji,nj->ni", L0, (r1 + o1) - (r0 + o0)).ravel(),
                      cay_inv(np.swapaxes(L0, 1, 2) @ L1).ravel()]
        return np.concatenate(parts) if parts else np.empty(0)

    def point_and_frames(self, q0, z):
        """:meth:`point` with the new level's re-orthonormalised frames ``Lam_1`` (the accepted step's data)."""
        pt = self.point(q0, z)
        if self.model.rod is not None:
            pt.Lam_1 = reorthonormalize(pt.Lam_n @ cay(pt.xi))
        return pt

    def retract(self, q0, z, floating_origin=False, pt=None):
        """The level vector q_{n+1} reached from ``q0`` by the step unknowns ``z``.

        Frames are re-orthonormalised (one polar Newton step: round-off, :func:`varint.rod.reorthonormalize`);
        with ``floating_origin`` the rod's origin follows node 0 on a binary grid (exact moves).  ``pt``: the
        step's :meth:`point_and_frames`, when the caller has it.
        """
        m = self.model
        parts = []
        if m.tube is not None:
            parts.append(z[m.tube_z][:m.tube.nq])
        if m.rod is not None:
            pt = pt if pt is not None else self.point_and_frames(q0, z)
            _, _, origin = unpack_level(q0[m.rod_q], m.rod.N)
            Lam_1 = pt.Lam_1.copy()
            r_1 = pt.r_1.copy()
            if m.rod.periodic:  # the image node is node 0 shifted by the period, exactly
                Lam_1[-1] = Lam_1[0]
                r_1[-1] = r_1[0] + m.rod.period
            if floating_origin:
                shift = origin_shift(r_1[0])
                r_1, origin = r_1 - shift, origin + shift
            parts.append(pack_level(Lam_1, r_1, origin))
        return np.concatenate(parts) if parts else np.empty(0)

    # -- L_d and its derivatives ------------------------------------------------------------

    def discrete_lagrangian(self, q0, q1, lam=None):
        """L_d(q0, q1, lam) = sum of the step terms' values."""
        pt = self.point(q0, self.unknowns(q0, q1, lam))
        return sum(t.value(pt) for t in self.terms)

    def _derivatives(self, pt, level):
        d = Derivatives(self.model)
        for t in self.terms:
            t.add(pt, d, level)
        return d

    def residual(self, q0, p0, z):
        """[p_n + D1 L_d + f^- ; D_lam L_d] at z (rod translational rows in the level-n body frames)."""
        m = self.model
        pt = self.point(q0, z)
        d = self._derivatives(pt, 0)
        for force in self.forces:
            force.add(pt, d, 0)
        parts = []
        if m.tube is not None:
            parts += [p0[m.tube_p] + d.tube_q, d.tube_lam]
        if m.rod is not None:
            rod = m.rod
            pi_n = p0[m.rod_p].reshape(2, rod.N + 1, 3).transpose(1, 0, 2).reshape(rod.N + 1, 6)
            R = pi_n + d.rod
            R[:, :3] = np.einsum("nji,nj->ni", pt.Lam_n, R[:, :3])
            parts.append(rod.fold(R)[rod.mask])
            if rod.constrained:
                parts.append(d.rod_lam[:, :rod.ncomp].ravel())
        return np.concatenate(parts) if parts else np.empty(0)

    def rigid_balances(self, q0, p0, z):
        """The step's linear and angular momentum balances at z in closed form, (P, J) (moments about the level's floating
        origin), and the 6x6 matrix G of their change -(1/h) G (a, w) along a rigid motion (a, w) of level n+1
        (docs/theory.md §10.6, "Momenta to round-off"): the momentum map of pi_n + D1 L_d + f^- with only the terms'
        pieces that rigid motions do not annihilate (their ``rigid_part``: inertia, weight, loads; the internal forces'
        sums vanish identically), and the forces' f^-."""
        m = self.model
        rod = m.rod
        pt = self.point(q0, z)
        d = Derivatives(m)
        points, spins = [], []
        for t in self.terms:
            if hasattr(t, "rigid_part"):
                pts, sp_ = t.rigid_part(pt, d)
                points.append(pts)
                if sp_ is not None:
                    spins.append(sp_)
        for force in self.forces:
            force.add(pt, d, 0)
        pi_n = p0[m.rod_p].reshape(2, rod.N + 1, 3).transpose(1, 0, 2).reshape(rod.N + 1, 6)
        R = pi_n + d.rod  # each node's momentum and inertial pieces combined before the sums (they nearly cancel)
        P = R[:, :3].sum(0)
        J = np.cross(pt.r_n, R[:, :3]).sum(0) + np.einsum("nij,nj->i", pt.Lam_n, R[:, 3:])
        G = np.zeros((6, 6))
        eye = np.eye(3)
        for mass, x0, x1 in points:
            G[:3, :3] += mass.sum() * eye
            S0, S1 = (mass[:, None] * x0).sum(0), (mass[:, None] * x1).sum(0)
            G[:3, 3:] -= hat(S1)
            G[3:, :3] += hat(S0)
            G[3:, 3:] += float(np.einsum("n,ni,ni->", mass, x0, x1)) * eye - np.einsum("n,ni,nj->ij", mass, x1, x0)
        for inertia, Lam in spins:  # dk/dxi = I + O(xi): enough for one correction of the floor's size
            G[3:, 3:] += np.einsum("nia,na,nja->ij", Lam, inertia, Lam)
        return P, J, G, pt

    def rigid_polish(self, q0, p0, z):
        """z moved along the six rigid motions of level n+1 so that the closed-form momentum balances of
        :meth:`rigid_balances` vanish: b_j += Lambda_j^T (a + w x r_j^{n+1}), xi_j += dcay^-1_{xi_j} Lambda_j^T w (on the
        support mask).  The motion leaves every strain of level n+1, the labels and the radii unchanged, so the other
        rows keep their floor; it is of the size of Newton's floor (docs/theory.md §10.6, "Momenta to round-off")."""
        m = self.model
        rod = m.rod
        P, J, G, pt = self.rigid_balances(q0, p0, z)
        aw = np.linalg.solve(G, self.h * np.concatenate([P, J]))
        a, w = aw[:3], aw[3:]
        u = np.zeros((rod.N + 1, 6))
        Lt = np.swapaxes(pt.Lam_n, 1, 2)
        u[:, :3] = np.einsum("nij,nj->ni", Lt, a + np.cross(w, pt.r_n + pt.dr))
        s = Lt @ w
        x = pt.xi
        u[:, 3:] = s - 0.5 * np.cross(x, s) + 0.25 * np.sum(x * s, axis=1)[:, None] * x
        z = z.copy()
        z[m.rod_z] += u.ravel()[self._rod_flat]
        return z

    def jacobian(self, q0, z):
        """Exact d(residual)/dz: the sum of the terms' blocks and of the forces' (None when a force's f^-
        reads level n only)."""
        pt = self.point(q0, z)
        J = None
        for t in list(self.terms) + self.forces:
            b = t.jacobian(pt)
            if b is not None:
                J = b if J is None else J + b
        return sp.csc_matrix(J) if J is not None else sp.csc_matrix((0, 0))

    def momentum_plus(self, q0, z, pt=None):
        """p_{n+1} = D2 L_d + f^+ (the rod's on every node); ``pt`` as in :meth:`retract`."""
        m = self.model
        pt = pt if pt is not None else self.point_and_frames(q0, z)
        d = self._derivatives(pt, 1)
        for force in self.forces:
            force.add(pt, d, 1)
        parts = []
        if m.tube is not None:
            parts.append(d.tube_q)
        if m.rod is not None:
            D2 = m.rod.fold(d.rod)  # a periodic rod's image node holds no momentum of its own
            parts += [D2[:, :3].ravel(), D2[:, 3:].ravel()]
        return np.concatenate(parts) if parts else np.empty(0)

    def step_energies(self, q0, z):
        """The tube's potential energies at the step's midpoint (its energy monitor with algebraic unknowns)."""
        pt = self.point(q0, z)
        term = next(t for t in self.terms if t.name == "tube_potential")
        return term.energies(pt)

    def explicit(self):
        """True when the residual is affine in z with a constant diagonal Jacobian (Stormer-Verlet on the
        tube): one linear solve is then the exact step, no Newton iteration is needed."""
        return all(t.constant_diagonal_jacobian() for t in self.terms) and not self.forces


def make_scheme(model, h, name=None, forces=None):
    """The :class:`Step` of ``model`` with time step ``h``, quadrature ``name`` (default: the scene's) and ``forces``
    (default: the model's)."""
    return Step(model, h, name, forces)
