"""The geometrically exact rod on the SE(3) lattice: a Cayley-map Lie-group variational integrator.

Lattice (docs/theory.md §9): nodes j = 0..N carry positions r_j and frames Lambda_j in SO(3).  A time step
n -> n+1 is parametrised by xi_j = cay^-1(Lambda_j^n^T Lambda_j^{n+1}) (= h omega_j) and r_j^{n+1}.

Discrete Lagrangian of a step (docs/theory.md §9), a sum over elements e = (j, j+1):

    L_d = sum_e h ds mu_e [ (k_j + k_{j+1})/2 - W_e + rhoA g.(rm_j + rm_{j+1})/2 ] + h F.rm_N
    k_j  = 1/2 rhoA |r_j^{n+1} - r_j^n|^2 / h^2 + 1/2 xi_j^T I xi_j / h^2          (kinetic density)
    W_e  = 1/2 Om_e^T J Om_e + 1/2 (Ga_e - chi)^T K (Ga_e - chi)                   (elastic density)
    Om_e = (Omega_e^n + Omega_e^{n+1}) / 2,  Ga_e = (Gamma_e^n + Gamma_e^{n+1}) / 2    (strain midpoint)
    Omega_e = cay^-1(Lambda_j^T Lambda_{j+1}) / ds,  Gamma_e = 1/2 (Lambda_j + Lambda_{j+1})^T (r_{j+1} - r_j) / ds
    rm_j = (r_j^n + r_j^{n+1}) / 2,   mu_e = |Ga_e| (the paper's measure) or 1 (reference-length measure)

Its derivatives with respect to the Lie-group variations Lambda -> Lambda cay(eps sigma),
r -> r + eps dr are element-local and exact: ``k_element`` returns an element's L_d and its analytic
gradient at both levels (dcay^-1 formulas, docs/theory.md §9); the step solves, in position-momentum form,

    pi_n + D1 L_d(q_n, q_{n+1}) + f^-_n = 0,       pi_{n+1} = D2 L_d(q_n, q_{n+1}) + f^+_n,

where pi = (p, Pi) are the linear (spatial) and angular (body) momenta and f^± = (h/2)(0, Lambda^T T)
the tip torque by Lagrange-d'Alembert.  Newton's Jacobian is assembled from element blocks, each the
complex step of the analytic element gradient (``_k_step_blocks``: exact to round-off, block
tridiagonal in nodes); statics and modes use the same for the Hessian of the potential
(``_k_static_blocks``).  The complex step of the whole L_d (``_k_pieces``) is kept as the tested reference.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
from numba import njit

from .forces import Declaration, TipTorque, derive_invariants
from ..scene.initial import shape_profile
from ..lattice.lie import cay, cay_inv, k_body, k_cay, k_cay_inv

__all__ = ["RodSection", "RodPart", "rod_section", "banded_jacobian", "reorthonormalize", "pack_level", "unpack_level"]

EPS_CS = 1e-30  # complex-step size: no subtractive cancellation, any tiny value works
CHI = np.array([1.0, 0.0, 0.0])
#: refresh the Jacobian when a chord iteration contracts by less than this.  0.5 in 0.1, when a
#: finite-difference Jacobian cost about 40 residuals; the exact one costs 7-15 (docs/performance.md,
#: "Exact rod Jacobian"), and 0.15 takes the 100-element tumbling rod from 15 to 11.5 iterations per
#: step, 1.8 to 1.5 ms.  (Iterating the chord to tol 1e-14 was tried: below the round-off floor of a
#: stiff rod's step, ~2e-13 at cond(J) = 5e5, it stalled a 10^6-step run at step 61536.)
RATE_REFRESH_ROD = 0.15
#: iterations past newton_tol down to the round-off floor: a step's momentum error is its final
#: residual, and over 10^4 tumbling steps tolerance-sized residuals added up to 3e-12 of the angular
#: momentum (1.7e-14 when polished; docs/validation.md)
POLISH_ROD = 10
#: largest accepted rotation per step, |xi| = 2 tan(theta/2) at theta = 90 degrees
XI_MAX = 2.0


def reorthonormalize(Lam):
    """One Newton step of the polar projection onto SO(3): Lambda (3 I - Lambda^T Lambda) / 2.

    Products of Cayley factors leave SO(3) by a random walk of round-off (3e-13 after 10^6 steps);
    the discrete momentum map assumes Lambda^-1 = Lambda^T, so that defect leaks into the angular
    momentum.  The correction is second order in the defect, i.e. it restores orthogonality to
    round-off and moves Lambda by a round-off amount.
    """
    return 0.5 * Lam @ (3.0 * np.eye(3) - np.swapaxes(Lam, -1, -2) @ Lam)


@dataclass(frozen=True)
class RodSection:
    """Per-unit-length section properties (SI)."""

    rhoA: float  #: mass per length [kg/m]
    rhoI: float  #: rotary inertia about a bending axis per length [kg m]
    EI: float  #: bending stiffness [N m^2]
    GJ: float  #: torsional stiffness [N m^2]
    EA: float  #: axial stiffness [N]
    kGA: float  #: shear stiffness [N]

    @property
    def inertia(self):
        """Body inertia per length diag(polar, bending, bending); the rod axis is E1."""
        return np.array([2.0 * self.rhoI, self.rhoI, self.rhoI])

    @property
    def J(self):
        return np.array([self.GJ, self.EI, self.EI])

    @property
    def K(self):
        return np.array([self.EA, self.kGA, self.kGA])


def rod_section(rod, inner_radius):
    """Section of a scene's ``[rod]``: stiffness form, or an annulus of the given thickness."""
    if rod.bending_stiffness is not None:
        # an inextensible, unshearable rod may leave its axial and shear stiffness out (it has no such energy)
        return RodSection(rod.mass_per_length, rod.rotary_inertia, rod.bending_stiffness, rod.torsional_stiffness,
                          rod.axial_stiffness if rod.axial_stiffness is not None else math.inf,
                          rod.shear_stiffness if rod.shear_stiffness is not None else math.inf)
    ri = inner_radius
    ro = ri + rod.thickness
    A = math.pi * (ro ** 2 - ri ** 2)
    I = math.pi * (ro ** 4 - ri ** 4) / 4.0
    E, rho = rod.youngs_modulus, rod.density
    G = rod.shear_modulus if rod.shear_modulus is not None else E / 3.0
    return RodSection(rho * A, rho * I, E * I, G * 2.0 * I, E * A, rod.shear_coefficient * G * A)


# ---------------------------------------------------------------------------
# the discrete Lagrangian, complex-step ready (leading batch axes allowed on every argument)


def _T(A):
    return np.swapaxes(A, -1, -2)


class RodPart:
    """Unknowns, section, loads and element kernels of a scene's ``[rod]``: the r and Lambda blocks of the model."""

    def __init__(self, scene):
        rod = scene.rod
        self.scene = scene
        self.L = scene.tube.length
        self.N = scene.tube.nodes - 1
        self.ds = self.L / self.N
        self.dim = rod.dimension
        self.section = rod_section(rod, scene.tube.radius)
        self.paper_measure = rod.measure == "paper"
        self.g = np.array(scene.environment.gravity, dtype=float)
        load = rod.load or {}
        self.force = np.array(load.get("force") or (0.0, 0.0, 0.0), dtype=float)
        self.torque = np.array(load.get("torque") or (0.0, 0.0, 0.0), dtype=float)
        #: non-conservative forces (discrete Lagrange-d'Alembert, varint.terms.forces)
        self.forces = [TipTorque(self.torque)] if np.any(self.torque) else []
        # active per-node directions: (dr_x, dr_y, dr_z, sigma_x, sigma_y, sigma_z)
        dirs = np.array([True] * 6) if self.dim == 3 else np.array([True, True, False, False, False, True])
        mask = np.tile(dirs, (self.N + 1, 1))
        for node, kind in ((0, rod.ends.s0), (self.N, rod.ends.sL)):
            if kind in ("clamped", "pinned"):
                mask[node, :3] = False
            if kind == "clamped":
                mask[node, 3:] = False
        #: periodic ends (docs/theory.md §9b): node N is node 0's image, r_N = r_0 + d (d = L E_1, the period),
        #: Lambda_N = Lambda_0; it holds no unknowns of its own, its rows fold into node 0's
        self.periodic = rod.ends.s0 == "periodic"
        self.period = np.array([self.L, 0.0, 0.0])
        if self.periodic:
            mask[self.N, :] = False
        self.mask = mask
        #: both ends free (or periodic): the rod can translate and turn as a whole (the mask cannot say it for the
        #: planar model, whose out-of-plane directions are masked everywhere)
        self.free = (rod.ends.s0 == "free" and rod.ends.sL == "free") or self.periodic
        self.nz = int(mask.sum())
        self.layout = {"r": int(mask[:, :3].sum()), "Lambda": int(mask[:, 3:].sum())}
        #: the inextensible, unshearable rod (docs/theory.md §9a, varint.terms.rod_constraint): Gamma = chi imposed by
        #: multipliers (level unknowns of the step's first level, SHAKE; ``ncomp`` per element) instead of the
        #: stretch-shear energy
        self.constrained = rod.constraint == "inextensible_unshearable"
        self.ncomp = 3 if self.dim == 3 else 2
        self.nlam = self.N * self.ncomp if self.constrained else 0
        if self.constrained:
            held = [e for e in (rod.ends.s0, rod.ends.sL) if e in ("clamped", "pinned")]
            if len(held) == 2 and not any((rod.initial or {}).get("curvature") or ()):
                # sum_e ds dGamma_1,e = (dr_N - dr_0).t = 0: the tension of a taut inextensible rod between two
                # held ends is indeterminate (one multiplier is free, the Newton matrix singular)
                raise ValueError("rod.constraint: a straight inextensible rod held at both ends has an indeterminate "
                                 "tension; give rod.initial.curvature, free an end, or use constraint = 'none'")
            if (rod.initial or {}).get("shape") == "steady_rotation":
                raise ValueError("rod.initial.shape: 'steady_rotation' is not available with rod.constraint = "
                                 "'inextensible_unshearable' in this version (its statics need the constraint)")
        self.w = np.full(self.N + 1, self.ds)
        self.w[0] = self.w[-1] = 0.5 * self.ds
        if self.periodic:  # node 0 carries both halves of its lumped mass, its image none
            self.w[0], self.w[-1] = self.ds, 0.0
        #: lumped node masses rho A w_j and section inertias I w_j (the kinetic metric, reference measure)
        self.node_mass = self.section.rhoA * self.w
        self.node_inertia = self.section.inertia[None, :] * self.w[:, None]
        self.perturbations = rod.perturbation or []
        self._initial(rod.initial or {})
        #: the steady rotation's Newton report when rod.initial.shape = "steady_rotation" (the model solves it:
        #: varint.model.model.statics.static_equilibrium), else None
        self.steady_rotation = None

    # -- initial state -------------------------------------------------------

    def _initial(self, ini):
        N, ds = self.N, self.ds
        kappa = np.array(ini.get("curvature") or (0.0, 0.0, 0.0), dtype=float)
        Lam = np.empty((N + 1, 3, 3))
        r = np.zeros((N + 1, 3))
        Lam[0] = np.eye(3)
        step = cay(ds * kappa)
        for j in range(N):
            Lam[j + 1] = Lam[j] @ step
            # strain-free chord: 1/2 (L_j + L_{j+1})^T dr / ds = chi
            r[j + 1] = r[j] + ds * np.linalg.solve(0.5 * (Lam[j] + Lam[j + 1]).T, CHI)
        self.velocity = np.array(ini.get("velocity") or (0.0, 0.0, 0.0), dtype=float)
        self.spin = np.array(ini.get("angular_velocity") or (0.0, 0.0, 0.0), dtype=float)
        #: rod.perturbation[]: node velocities added to the rigid motion, profiles along the reference arc length
        self.velocity_perturbation = np.zeros((N + 1, 3))
        s_nodes = ds * np.arange(N + 1)
        for p in self.perturbations:
            d = np.asarray(p.direction, dtype=float)
            self.velocity_perturbation += shape_profile(p, s_nodes)[:, None] * (d / np.linalg.norm(d))[None, :]
        self.velocity_perturbation *= self.mask[:, :3]  # a held node does not move
        self.set_configuration(Lam, r)

    @property
    def K_energy(self):
        """The stretch-shear stiffness of the energy: the section's, or zero when the constraint replaces it."""
        return np.zeros(3) if self.constrained else self.section.K

    def centre_of_mass(self, r):
        return (self.node_mass[:, None] * r).sum(0) / self.node_mass.sum()

    def set_configuration(self, Lam, r, rest=False):
        """Start from (Lam, r), moving rigidly with rod.initial velocity and angular velocity about its
        centre of mass (e.g. the steady rotation found by :func:`static_equilibrium` with ``spin``), or
        at rest (``rest=True``: a static equilibrium)."""
        v = self.velocity + np.cross(self.spin, r - self.centre_of_mass(r)) + self.velocity_perturbation
        omega = np.einsum("nji,j->ni", Lam, self.spin)  # body angular velocity Lambda^T Omega
        if rest:
            v, omega = np.zeros_like(v), np.zeros_like(omega)
        self.Lam0, self.r0 = Lam, r
        self.v0, self.omega0 = v, omega
        self.p0 = self.node_mass[:, None] * v
        self.Pi0 = self.node_inertia * omega

    # -- discrete Lagrangian pieces ---------------------------------------------

    def strains(self, Lam, r):
        """Element strains at one level: Omega = cay^-1(L_j^T L_{j+1})/ds, Gamma = 1/2 (L_j + L_{j+1})^T dr / ds
        (:func:`level_strains`; leading batch axes, real or complex)."""
        st = level_strains(Lam, r, self.ds)
        return st.Omega, st.Gamma

    def lagrangian_pieces(self, h, Lam_n, r_n, xi, r_1, sig=None, dr=None, level=0):
        """Per-element discrete Lagrangian (B, N) and per-node extra pieces (B, N+1).

        ``sig``, ``dr`` (B, N+1, 3) perturb the level ``level`` (0: n, 1: n+1) configuration:
        Lambda -> Lambda cay(sig), r -> r + dr.  Complex values give complex-step derivatives.
        The potential is evaluated at the *strain midpoint* (eps_n + eps_{n+1})/2: exact for rigid
        motions of any size, the implicit midpoint rule on linear problems (docs/theory.md §9).
        """
        Lam_1 = Lam_n @ cay(xi)
        if sig is not None:
            C = cay(sig)
            if level == 0:
                Lam_n = Lam_n @ C
                xi = cay_inv(_T(C) @ cay(xi))
                r_n = r_n + dr
            else:
                Lam_1 = Lam_1 @ C
                xi = cay_inv(cay(xi) @ C)
                r_1 = r_1 + dr
        sec, ds = self.section, self.ds
        vel = (r_1 - r_n) / h
        k = 0.5 * sec.rhoA * np.sum(vel * vel, axis=-1) + 0.5 * np.sum(sec.inertia * xi * xi, axis=-1) / h ** 2
        Om0, Ga0 = self.strains(Lam_n, r_n)
        Om1, Ga1 = self.strains(Lam_1, r_1)
        Om, Ga = 0.5 * (Om0 + Om1), 0.5 * (Ga0 + Ga1)
        dG = Ga - CHI
        W = 0.5 * np.sum(sec.J * Om * Om, axis=-1) + 0.5 * np.sum(self.K_energy * dG * dG, axis=-1)
        mu = np.sqrt(np.sum(Ga * Ga, axis=-1)) if self.paper_measure else 1.0
        rm = 0.5 * (r_n + r_1)
        grav = sec.rhoA * np.sum(self.g * (rm[..., :-1, :] + rm[..., 1:, :]), axis=-1) * 0.5
        elem = h * ds * mu * (0.5 * (k[..., :-1] + k[..., 1:]) - W + grav)
        node = np.zeros(rm.shape[:-1], dtype=elem.dtype)
        node[..., -1] = h * np.sum(self.force * rm[..., -1, :], axis=-1)
        return elem, node

    def pieces_fast(self, h, Lam_n, r_n, xi, r_1, sig, dr, level, load_factor=1.0):
        """:meth:`lagrangian_pieces` through the numba kernel ``_k_pieces`` (tested equal)."""
        sec = self.section
        c = np.complex128
        B = sig.shape[0]
        elem = np.empty((B, self.N), dtype=c)
        node = np.empty((B, self.N + 1), dtype=c)
        consts = getattr(self, "_cs_consts", None)
        if consts is None or consts[0] != load_factor:  # the kernel's complex constants, built once per load
            consts = (load_factor, sec.inertia.astype(c), sec.J.astype(c), self.K_energy.astype(c),
                      (load_factor * self.g).astype(c), (load_factor * self.force).astype(c))
            self._cs_consts = consts
        # the levels are real (only the perturbations sig, dr are complex): no conversion needed
        f8 = np.float64
        _k_pieces(float(h), self.ds, np.ascontiguousarray(Lam_n, dtype=f8), np.ascontiguousarray(r_n, dtype=f8),
                  np.ascontiguousarray(xi, dtype=f8), np.ascontiguousarray(r_1, dtype=f8), np.ascontiguousarray(sig, dtype=c),
                  np.ascontiguousarray(dr, dtype=c), level, sec.rhoA, *consts[1:], self.paper_measure, elem, node)
        return elem, node

    def node_index(self):
        """(N+1, 6) index of each node's (dr, sigma) in the rod's unknowns, -1 where held; a periodic rod's
        image node N takes node 0's (its rows and columns fold into node 0's)."""
        idx = np.full((self.N + 1, 6), -1)
        idx[self.mask] = np.arange(self.nz)
        if self.periodic:
            idx[self.N] = idx[0]
        return idx

    @property
    def column_mask(self):
        """The directions whose columns the element kernels compute: the mask, and a periodic rod's image node
        as node 0 (its columns fold into node 0's)."""
        if not self.periodic:
            return self.mask
        m = self.mask.copy()
        m[self.N] = m[0]
        return m

    def fold(self, D):
        """A periodic rod's (N+1, 6) derivative with the image node's rows added into node 0's (in place)."""
        if self.periodic:
            D[0] += D[self.N]
            D[self.N] = 0.0
        return D

    def level_energy(self, Lam, r, p, Pi, origin=None):
        """Energy H(q_n, pi_n) = kinetic from the discrete momenta + potential at the level (the monitor).

        ``r`` may be relative to ``origin`` (the floating origin of a free rod): the potentials of
        gravity and the tip force, linear in r, take the origin's part separately.
        """
        sec, ds = self.section, self.ds
        Om, Ga = self.strains(Lam, r)
        dG = Ga - CHI
        mu = np.sqrt(np.sum(Ga * Ga, axis=-1)) if self.paper_measure else np.ones(self.N)
        wmu = np.zeros(self.N + 1)  # nodal weights of the (possibly |Gamma|-weighted) lumped mass
        wmu[:-1] += 0.5 * ds * mu
        wmu[1:] += 0.5 * ds * mu
        if self.periodic:  # the image node's half belongs to node 0 (its momenta are folded there)
            wmu[0] += wmu[-1]
            wmu[-1] = np.inf
        kin = float(np.sum(np.sum(p * p, 1) / (sec.rhoA * wmu)) * 0.5
                    + np.sum(np.sum(Pi * Pi / sec.inertia, 1) / wmu) * 0.5)
        bend = float(np.sum(ds * mu * 0.5 * np.sum(sec.J * Om * Om, axis=-1)))
        stretch = float(np.sum(ds * mu * 0.5 * np.sum(self.K_energy * dG * dG, axis=-1)))
        grav = -float(np.sum(ds * mu * sec.rhoA * np.sum(self.g * (r[:-1] + r[1:]), axis=-1) * 0.5))
        load = -float(np.dot(self.force, r[-1]))
        if origin is not None and np.any(origin):
            grav -= float(np.sum(ds * mu) * sec.rhoA * np.dot(self.g, origin))
            load -= float(np.dot(self.force, origin))
        return {"kinetic": kin, "bending_torsion": bend, "stretch_shear": stretch, "gravity": grav, "load": load}

    def _cs_plan(self):
        """Complex-step perturbations (built once): all even, then all odd nodes, one direction each.

        Returns ``(sig, dr, colour, direction)``: batch b perturbs direction ``direction[b]`` (0-2:
        dr, 3-5: sigma) of the nodes of parity ``colour[b]``.
        """
        if getattr(self, "_plan", None) is None:
            N = self.N
            dirs = [0, 1, 5] if self.dim == 2 else list(range(6))
            colour = np.repeat([0, 1], len(dirs))
            direction = np.tile(dirs, 2)
            sig = np.zeros((len(colour), N + 1, 3), dtype=complex)
            dr = np.zeros((len(colour), N + 1, 3), dtype=complex)
            for b, (c, d) in enumerate(zip(colour, direction)):
                if d < 3:
                    dr[b, c::2, d] = 1j * EPS_CS
                else:
                    sig[b, c::2, d - 3] = 1j * EPS_CS
            self._plan = (sig, dr, colour, direction)
        return self._plan

    def _consts(self, load_factor=1.0):
        """Section and load arrays of the exact kernels (built once per load factor)."""
        c = getattr(self, "_exact_consts", None)
        if c is None or c[0] != load_factor:
            sec = self.section
            c = (load_factor, sec.rhoA, np.ascontiguousarray(sec.inertia, dtype=float), np.ascontiguousarray(sec.J, dtype=float),
                 np.ascontiguousarray(self.K_energy, dtype=float), load_factor * self.g, load_factor * self.force)
            self._exact_consts = c
        return c

    def gradients(self, h, Lam_n, r_n, xi, r_1, load_factor=1.0, levels=(0, 2), dr=None, elastic=True):
        """(D1, D2, L_d): d L_d / d(dr, sigma) at levels n and n+1, each (N+1, 6), from the analytic
        element gradients (``k_element`` summed by ``k_rod_gradient``; docs/theory.md §9), and the value of L_d.
        ``levels``: the range of levels computed ((0, 1): D1 only, (1, 2): D2 only; the other is returned as zeros).
        ``dr``: the increments r_1 - r_n when the caller has them unrounded (the step's Lambda_n b), else formed here;
        ``elastic=False``: the kinetic, weight and tip-force pieces only (the stiffnesses set to zero)."""
        _, rhoA, inertia, J, K, g, force = self._consts(load_factor)
        if not elastic:
            J, K = np.zeros(3), np.zeros(3)
        f8 = np.float64
        Lam_n = np.ascontiguousarray(Lam_n, dtype=f8)
        r_n = np.ascontiguousarray(r_n, dtype=f8)
        dr = np.ascontiguousarray(np.asarray(r_1, dtype=f8) - r_n if dr is None else dr, dtype=f8)
        D1 = np.zeros((self.N + 1, 6))
        D2 = np.zeros((self.N + 1, 6))
        try:
            L = _k_rod_gradient(float(h), self.ds, rhoA, inertia, J, K, g, force, self.paper_measure, Lam_n, r_n,
                                np.ascontiguousarray(xi, dtype=f8), dr, levels[0], levels[1], D1, D2)
        except ZeroDivisionError:
            # a Newton iterate turned some frame, or some element's relative rotation, by pi: the Cayley
            # chart is singular there.  Not finite: Newton backtracks or reports the step as failed.
            D1[:] = np.nan if levels[0] == 0 else 0.0
            D2[:] = np.nan if levels[1] == 2 else 0.0
            L = np.nan
        return D1, D2, L

    def derivative(self, h, Lam_n, r_n, xi, r_1, level, load_factor=1.0):
        """d L_d / d(dr, sigma) at level 0 (D1) or 1 (D2): array (N+1, 6), exact (analytic element gradients)."""
        return self.gradients(h, Lam_n, r_n, xi, r_1, load_factor, (level, level + 1))[level]

    def _block_pattern(self):
        """Rows, columns (on the mask) and kept entries of the element blocks (N, 12, 12), built once."""
        if getattr(self, "_pattern", None) is None:
            N = self.N
            idx = self.node_index().ravel()
            e = np.arange(N)[:, None]
            loc = np.arange(12)[None, :]
            glob = (e + loc // 6) * 6 + loc % 6  # (N, 12) full index of each block row/column
            rows = np.broadcast_to(idx[glob][:, :, None], (N, 12, 12)).ravel()
            cols = np.broadcast_to(idx[glob][:, None, :], (N, 12, 12)).ravel()
            keep = (rows >= 0) & (cols >= 0)
            self._pattern = (rows[keep], cols[keep], keep)
        return self._pattern

    def assemble(self, blocks):
        """Sparse (nz, nz) CSC matrix on the mask from element blocks (N, 12, 12) (block tridiagonal in nodes)."""
        rows, cols, keep = self._block_pattern()
        return sp.csc_matrix((blocks.ravel()[keep], (rows, cols)), shape=(self.nz, self.nz))

    def step_jacobian(self, h, Lam_n, r_n, xi, r_1):
        """Exact Jacobian of the step residual pi_n + D1 L_d + f^- (translational rows in the level-n body
        frame) with respect to the unknowns (b, xi) on the mask: element blocks by complex step of the
        analytic element gradient (``_k_step_blocks``), assembled.  The tip torque's f^- does not depend
        on the unknowns."""
        _, rhoA, inertia, J, K, g, force = self._consts()
        blocks = np.empty((self.N, 12, 12))
        f8 = np.float64
        _k_step_blocks(float(h), self.ds, rhoA, inertia, J, K, g, self.paper_measure,
                       np.ascontiguousarray(Lam_n, dtype=f8), np.ascontiguousarray(r_n, dtype=f8),
                       np.ascontiguousarray(xi, dtype=f8), np.ascontiguousarray(r_1, dtype=f8), self.column_mask, EPS_CS, blocks)
        return self.assemble(blocks)

    def potential_hessian(self, Lam, r, load_factor=1.0):
        """Exact d(-grad U)/dz (nz, nz) at (Lam, r) under Lambda cay(sigma), r + dr: the derivative of the
        generalised force (tip torque included) that rod_statics' Newton and modes need."""
        _, rhoA, inertia, J, K, g, force = self._consts(load_factor)
        blocks = np.empty((self.N, 12, 12))
        _k_static_blocks(self.ds, rhoA, inertia, J, K, g, self.paper_measure, np.ascontiguousarray(Lam, dtype=np.float64),
                         np.ascontiguousarray(r, dtype=np.float64), self.column_mask, EPS_CS, blocks)
        for f in self.forces:  # the tip torque's generalised force turns with the tip frame
            blocks[-1, 9:, 9:] += load_factor * f.stiffness_block(Lam)
        return self.assemble(blocks)

    def derivative_complex_step(self, h, Lam_n, r_n, xi, r_1, level, load_factor=1.0):
        """d L_d / d(dr, sigma) at level 0 (D1) or 1 (D2) by complex step of the whole L_d (``_k_pieces``):
        the independent reference of the analytic :meth:`derivative` (tested equal)."""
        sig, dr, colour, direction = self._cs_plan()
        try:
            elem, node = self.pieces_fast(h, Lam_n, r_n, xi, r_1, sig, dr, level, load_factor)
        except ZeroDivisionError:
            # a Newton iterate turned some frame, or some element's relative rotation, by pi: the Cayley
            # chart is singular there.  Not finite: Newton backtracks or reports the step as failed.
            return np.full((self.N + 1, 6), np.nan)
        out = np.zeros((self.N + 1, 6))
        _k_accumulate(elem, node, colour, direction, 1.0 / EPS_CS, out)
        return out

    def accumulate_reference(self, elem, node):
        """NumPy twin of ``_k_accumulate`` (tested equal): each element's derivative goes to the one
        node of the perturbed colour it touches, plus the node pieces of that colour."""
        N = self.N
        _, _, colour, direction = self._cs_plan()
        de, dn = elem.imag / EPS_CS, node.imag / EPS_CS
        out = np.zeros((N + 1, 6))
        e = np.arange(N)
        owners = (np.where(e % 2 == 0, e, e + 1), np.where(e % 2 == 1, e, e + 1))
        for b, (c, d) in enumerate(zip(colour, direction)):
            out[:, d] += np.bincount(owners[c], weights=de[b], minlength=N + 1)
            out[c::2, d] += dn[b, c::2]
        return out

    def generalised_forces(self, Lam, load_factor=1.0):
        """Static generalised force of the non-conservative forces, (N+1, 6)."""
        f = np.zeros((self.N + 1, 6))
        for force in self.forces:
            f += load_factor * force.generalised(Lam)
        return f

    def declarations(self):
        """What each term, force and end does to the invariants (varint.terms.forces.Declaration)."""
        decl = [Declaration(name) for name in ("rod_kinetic", "bending_torsion", "stretch_shear")]
        if np.any(self.g):
            decl.append(Declaration("gravity", {"linear_momentum": "linear_momentum_transverse_to_gravity",
                                                "angular_momentum": "angular_momentum_along_gravity"}))
        if np.any(self.force):  # a dead force at the tip: conservative (its potential -F.r_N), not symmetric
            decl.append(Declaration("tip_force", {"linear_momentum": None, "angular_momentum": None}))
        decl += [f.declaration for f in self.forces]
        ends = (self.scene.rod.ends.s0, self.scene.rod.ends.sL)
        if self.periodic:
            # translations keep the period d = L E_1; of the rotations only those about d do
            decl.append(Declaration("ends", {"angular_momentum": "angular_momentum_along_the_period"}))
        elif ends == ("pinned", "pinned") and self.dim == 3:
            # bearings at both ends: turning about the line through them keeps both pins in place
            decl.append(Declaration("ends", {"linear_momentum": None,
                                             "angular_momentum": "angular_momentum_about_the_bearing_axis"}))
        elif any(e in ("clamped", "pinned") for e in ends):
            decl.append(Declaration("ends", {"linear_momentum": None, "angular_momentum": None}))
        return decl

    def expected_invariants(self):
        """Derived from the declarations of the terms, forces and ends (varint.terms.forces.derive_invariants)."""
        return derive_invariants(self.declarations())

    def describe(self):
        s = self.section
        unknowns = {"r": self.layout["r"], "Lambda": self.layout["Lambda"]}
        if self.constrained:
            unknowns["n"] = self.nlam
        return {"effects": list(self.scene.effects), "unknowns": unknowns,
                "unknowns_total": self.nz + self.nlam, "inertial_unknowns": self.nz, "algebraic_unknowns": self.nlam,
                "terms": ["rod_kinetic", "bending_torsion", "inextensibility" if self.constrained else "stretch_shear"]
                + (["gravity"] if np.any(self.g) else [])
                + (["tip_force"] if np.any(self.force) else []),
                "forces": [f.declaration.name for f in self.forces],
                "invariants": self.expected_invariants(), "scheme": "midpoint",
                "initial_shape": "given" if self.steady_rotation is None else
                f"steady rotation ({self.steady_rotation['iterations']} Newton iterations, chord turned "
                f"{self.steady_rotation['turned_deg']:.3g} deg)",
                "lattice": {"elements": self.N, "ds": self.ds, "parcels": 0, "periodic": False},
                "rod": {"dimension": self.dim, "measure": "paper" if self.paper_measure else "reference",
                        "mass_per_length": s.rhoA, "bending_stiffness": s.EI, "torsional_stiffness": s.GJ,
                        # (None: not given, for the inextensible rod that has no such energy)
                        "axial_stiffness": s.EA if math.isfinite(s.EA) else None,
                        "shear_stiffness": s.kGA if math.isfinite(s.kGA) else None, "rotary_inertia": s.rhoI,
                        "constraint": "inextensible_unshearable" if self.constrained else "none"}}


def banded_jacobian(func, z, mask, ds, rel_step=1e-6):
    """Jacobian of a node-local map by colour-grouped central differences.

    ``func(z) -> (N+1, 6)`` must have the value at node j depend only on the unknowns of nodes
    j-1..j+1 (true of every derivative of the rod's L_d); three colours then cover the band, so the
    cost is 2 x 3 x (active directions) evaluations whatever N is.  Returns CSC (n, n) on the mask.
    """
    n_nodes = mask.shape[0]
    idx = np.full(mask.shape, -1)
    idx[mask] = np.arange(int(mask.sum()))
    rows, cols, vals = [], [], []
    for c in range(3):
        for d in range(6):
            nodes = np.arange(c, n_nodes, 3)
            nodes = nodes[mask[nodes, d]]
            if len(nodes) == 0:
                continue
            e = np.zeros(mask.shape)
            step = rel_step * (ds if d < 3 else 1.0)
            e[nodes, d] = step
            dz = e[mask]
            D = (func(z + dz) - func(z - dz)) / (2 * step)
            for j in nodes:
                lo, hi = max(j - 1, 0), min(j + 1, n_nodes - 1)
                ridx = idx[lo:hi + 1]
                keep = ridx >= 0
                rows.append(ridx[keep])
                cols.append(np.full(int(keep.sum()), idx[j, d]))
                vals.append(D[lo:hi + 1][keep])
    n = int(mask.sum())
    return sp.csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))


def pack_level(Lam, r, origin=None):
    """The rod's part of a level vector q: (positions relative to the origin, frames, origin)."""
    return np.concatenate([r.ravel(), Lam.ravel(), np.zeros(3) if origin is None else origin])


def unpack_level(q, N):
    """(Lambda, r relative to the origin, origin) from the rod's part of a level vector."""
    n3 = 3 * (N + 1)
    return q[n3:12 * (N + 1)].reshape(N + 1, 3, 3), q[:n3].reshape(N + 1, 3), q[12 * (N + 1):]


#: grid of the floating origin's moves (m): multiples of 2^-20 add exactly to an origin on the same grid
ORIGIN_GRID = 2.0 ** -20


def origin_shift(x):
    """The floating origin's move to the point x: x rounded to ORIGIN_GRID (subtracting it from nearby positions is exact)."""
    return np.round(x / ORIGIN_GRID) * ORIGIN_GRID


# ---------------------------------------------------------------------------
# numba kernel of RodPart.lagrangian_pieces (complex arithmetic, for the complex-step derivatives)


@njit(cache=True, inline="always")
def _k_mm(A, B, out):
    for i in range(3):
        for j in range(3):
            out[i, j] = A[i, 0] * B[0, j] + A[i, 1] * B[1, j] + A[i, 2] * B[2, j]


@njit(cache=True, inline="always")
def _k_mtm(A, B, out):
    """out = A^T B."""
    for i in range(3):
        for j in range(3):
            out[i, j] = A[0, i] * B[0, j] + A[1, i] * B[1, j] + A[2, i] * B[2, j]


# ---------------------------------------------------------------------------
# the strains of an element (docs/theory.md §9), the one place their formulas are written: every kernel of the rod
# (the step's element kernel, the constraint's, the paper measure, the fluid's stretch, the energy-momentum step's
# discrete gradient) and the NumPy functions (:func:`level_strains`) build on these.  Any scalar type (real, or
# complex for complex steps).


@njit(cache=True, inline="always")
def k_chords(La, Lb, d, pa, pb):
    """The element's chord d = r_b - r_a in the body frames of its two nodes: pa = La^T d, pb = Lb^T d."""
    for i in range(3):
        pa[i] = k_body(La, d, i)
        pb[i] = k_body(Lb, d, i)


@njit(cache=True, inline="always")
def k_gamma(La, Lb, d, ds, G):
    """Gamma = (La + Lb)^T d / (2 ds) (= (pa + pb) / (2 ds)) of an element at one level, d = r_b - r_a, into G."""
    for i in range(3):
        G[i] = 0.5 * ((La[0, i] + Lb[0, i]) * d[0] + (La[1, i] + Lb[1, i]) * d[1] + (La[2, i] + Lb[2, i]) * d[2]) / ds


@njit(cache=True, inline="always")
def k_gamma_mid(pa0_i, pb0_i, pa1_i, pb1_i, ds):
    """Component i of the strain midpoint Gammabar = (Gamma^n + Gamma^{n+1}) / 2 from both levels' chords."""
    return 0.25 * (pa0_i + pb0_i + pa1_i + pb1_i) / ds


@njit(cache=True, inline="always")
def k_turn(La, Lb, T, om):
    """The element's relative rotation T = La^T Lb and om = cay^-1(T) = ds Omega (its curvature times ds); returns
    (c, a0, a1, a2), c = 1 + tr T and a the axial vector of T - T^T (unhalved): om = 2 a / c."""
    _k_mtm(La, Lb, T)
    return k_cay_inv(T, om)


@njit(cache=True, inline="always")
def k_element_strains(La, Lb, d, ds, T, pa, pb, G, a, om):
    """An element's strains at one level: chords pa, pb (:func:`k_chords`), Gamma into G (:func:`k_gamma`), om = ds
    Omega and a (:func:`k_turn`); returns c = 1 + tr(La^T Lb)."""
    k_chords(La, Lb, d, pa, pb)
    k_gamma(La, Lb, d, ds, G)
    c, a[0], a[1], a[2] = k_turn(La, Lb, T, om)
    return c


@njit(cache=True, inline="always")
def k_strain_force(La, Lb, pa, pb, gG, ds, i):
    """Component i of A^T gG, the gradient in one level's variations [dr_a, sigma_a, dr_b, sigma_b] (dr spatial,
    Lambda -> Lambda cay(sigma)) of a function of the element's Gamma at that level whose Gamma-derivative is gG:
    (f, sa, sb) with the dr_a row -f, the dr_b row f and the sigma rows sa, sb.  dGamma/ddr_b = -dGamma/ddr_a =
    (La + Lb)^T / (2 ds), dGamma/dsigma_a = hat(pa) / (2 ds) (Lambda^T d turns into p + p x sigma), so sa = (gG x pa)_i
    / (2 ds).  (Per component, in registers: the rod's element kernel adds its other pieces before it stores a row.)"""
    j = (i + 1) % 3
    k = (i + 2) % 3
    f = ((La[i, 0] + Lb[i, 0]) * gG[0] + (La[i, 1] + Lb[i, 1]) * gG[1] + (La[i, 2] + Lb[i, 2]) * gG[2]) / (2.0 * ds)
    return f, (gG[j] * pa[k] - gG[k] * pa[j]) / (2.0 * ds), (gG[j] * pb[k] - gG[k] * pb[j]) / (2.0 * ds)


@njit(cache=True, inline="always")
def k_strain_gradient(La, Lb, pa, pb, gG, ds, D):
    """D (12) = A^T gG (:func:`k_strain_force`) in the layout [dr_a, sigma_a, dr_b, sigma_b]: the constraint's element
    kernel and the fluid's stretch force (varint.terms.coupled)."""
    for i in range(3):
        f, sa, sb = k_strain_force(La, Lb, pa, pb, gG, ds, i)
        D[i] = -f
        D[3 + i] = sa
        D[6 + i] = f
        D[9 + i] = sb


@njit(cache=True, inline="always")
def k_strain_gradients(L0a, L0b, L1a, L1b, pa0, pb0, pa1, pb1, gG, ds, lev_lo, lev_hi, D1, D2):
    """:func:`k_strain_gradient` of a function of the strain midpoint at the levels lev_lo <= level < lev_hi: level n
    (frames L0a, L0b, chords pa0, pb0) into D1, level n+1 into D2; gG is its derivative in either level's Gamma."""
    for lev in range(lev_lo, lev_hi):
        if lev == 0:
            k_strain_gradient(L0a, L0b, pa0, pb0, gG, ds, D1)
        else:
            k_strain_gradient(L1a, L1b, pa1, pb1, gG, ds, D2)


@njit(cache=True, inline="always")
def k_strains_row(Lam, r, ds, periodic, period, Om, Ga, pa, pb, a, c, T, d, om):
    """:func:`k_element_strains` of every element of a lattice: Lam (n, 3, 3), r (n, 3); elements (e, e + 1), and on a
    periodic lattice of n distinct nodes also (n - 1, 0) with the period (3,) added to its chord.  Writes Om (=
    Omega), Ga, pa, pb, a (n_el, 3) and c (n_el,); T (3, 3), d, om (3): scratch."""
    n = r.shape[0]
    for e in range(Om.shape[0]):
        f = (e + 1) % n
        for i in range(3):
            d[i] = r[f, i] - r[e, i]
            if periodic and e == n - 1:
                d[i] += period[i]
        c[e] = k_element_strains(Lam[e], Lam[f], d, ds, T, pa[e], pb[e], Ga[e], a[e], om)
        for i in range(3):
            Om[e, i] = om[i] / ds


@njit(cache=True)
def k_strains_rows(Lam, r, ds, periodic, period, Om, Ga, pa, pb, a, c):
    """:func:`k_strains_row` of each row b of a batch: Lam (B, n, 3, 3), r (B, n, 3) -> Om, Ga, pa, pb, a (B, n_el, 3),
    c (B, n_el)."""
    T = np.empty((3, 3), Om.dtype)
    d = np.empty(3, Om.dtype)
    om = np.empty(3, Om.dtype)
    for b in range(r.shape[0]):
        k_strains_row(Lam[b], r[b], ds, periodic, period, Om[b], Ga[b], pa[b], pb[b], a[b], c[b], T, d, om)


class Strains(NamedTuple):
    """The strains of every element at one level (:func:`level_strains`): Omega = cay^-1(La^T Lb) / ds, Gamma =
    (La + Lb)^T (r_b - r_a) / (2 ds), the chords pa = La^T (r_b - r_a), pb = Lb^T (r_b - r_a), and a, c with
    ds Omega = 2 a / c (a the axial vector of La^T Lb - Lb^T La, c = 1 + tr La^T Lb)."""

    Omega: np.ndarray
    Gamma: np.ndarray
    pa: np.ndarray
    pb: np.ndarray
    a: np.ndarray
    c: np.ndarray


def level_strains(Lam, r, ds, periodic=False, period=None):
    """:class:`Strains` of the elements of frames (or directors: any 3 x 3 matrices) ``Lam`` (..., n, 3, 3) and positions
    ``r`` (..., n, 3), leading batch axes broadcast, real or complex (through :func:`k_strains_rows`).  Elements
    (j, j + 1); ``periodic``: n distinct nodes and a closing element (n - 1, 0) whose chord adds ``period`` (default
    n ds E_1)."""
    Lam, r = np.asarray(Lam), np.asarray(r)
    dt = np.result_type(Lam, r, np.float64)
    batch = np.broadcast_shapes(Lam.shape[:-3], r.shape[:-2])
    n = r.shape[-2]
    n_el = n if periodic else n - 1
    L2 = np.ascontiguousarray(np.broadcast_to(Lam, batch + (n, 3, 3)), dtype=dt).reshape(-1, n, 3, 3)
    r2 = np.ascontiguousarray(np.broadcast_to(r, batch + (n, 3)), dtype=dt).reshape(-1, n, 3)
    B = r2.shape[0]
    d = np.array([n * ds, 0.0, 0.0]) if period is None else np.asarray(period, dtype=np.float64).reshape(3)
    Om, Ga, pa, pb, a = (np.empty((B, n_el, 3), dt) for _ in range(5))
    c = np.empty((B, n_el), dt)
    k_strains_rows(L2, r2, float(ds), bool(periodic), d.astype(dt), Om, Ga, pa, pb, a, c)
    v3 = batch + (n_el, 3)
    return Strains(Om.reshape(v3), Ga.reshape(v3), pa.reshape(v3), pb.reshape(v3), a.reshape(v3), c.reshape(batch + (n_el,)))


@njit(cache=True)
def _k_accumulate(elem, node, plan_colour, plan_dir, inv_eps, out):
    """out[j, d] += Im(elem)/eps of the elements touching j (one colour per batch) and Im(node)/eps of j."""
    B, N = elem.shape
    for b in range(B):
        c, d = plan_colour[b], plan_dir[b]
        for e in range(N):
            owner = e if e % 2 == c else e + 1
            out[owner, d] += elem[b, e].imag * inv_eps
        for j in range(c, N + 1, 2):
            out[j, d] += node[b, j].imag * inv_eps


@njit(cache=True)
def _k_pieces(h, ds, Lam_n, r_n, xi, r_1, sig, dr, level, rhoA, inertia, Jd, Kd, g, force, paper, elem, node):
    """elem[b, e], node[b, j] of L_d for every perturbation b (see RodPart.lagrangian_pieces)."""
    B = sig.shape[0]
    N = Lam_n.shape[0] - 1
    C = np.empty((3, 3), dtype=np.complex128)
    T = np.empty((3, 3), dtype=np.complex128)
    Ln = np.empty((N + 1, 3, 3), dtype=np.complex128)
    L1 = np.empty((N + 1, 3, 3), dtype=np.complex128)
    rn = np.empty((N + 1, 3), dtype=np.complex128)
    r1 = np.empty((N + 1, 3), dtype=np.complex128)
    xp = np.empty((N + 1, 3), dtype=np.complex128)
    k = np.empty(N + 1, dtype=np.complex128)
    Om0 = np.empty((N, 3), dtype=np.complex128)
    Ga0 = np.empty((N, 3), dtype=np.complex128)
    Om1 = np.empty((N, 3), dtype=np.complex128)
    Ga1 = np.empty((N, 3), dtype=np.complex128)
    # scratch of k_strains_row (chords, axial vectors, c; a vector and om)
    spa, spb, sa = np.empty((N, 3), np.complex128), np.empty((N, 3), np.complex128), np.empty((N, 3), np.complex128)
    sc, sd, som = np.empty(N, np.complex128), np.empty(3, np.complex128), np.empty(3, np.complex128)
    per = np.zeros(3)
    # the unperturbed level and cay(xi) are the same for every batch: compute them once
    Cxs = np.empty((N + 1, 3, 3), dtype=np.complex128)
    for j in range(N + 1):
        k_cay(xi[j, 0], xi[j, 1], xi[j, 2], Cxs[j])
        if level == 0:
            _k_mm(Lam_n[j], Cxs[j], L1[j])
            for i in range(3):
                r1[j, i] = r_1[j, i]
        else:
            for i in range(3):
                rn[j, i] = r_n[j, i]
                for m in range(3):
                    Ln[j, i, m] = Lam_n[j, i, m]
    if level == 0:
        k_strains_row(L1, r1, ds, False, per, Om1, Ga1, spa, spb, sa, sc, T, sd, som)
    else:
        k_strains_row(Ln, rn, ds, False, per, Om0, Ga0, spa, spb, sa, sc, T, sd, som)
    for b in range(B):
        for j in range(N + 1):
            Cx = Cxs[j]
            k_cay(sig[b, j, 0], sig[b, j, 1], sig[b, j, 2], C)
            if level == 0:
                _k_mm(Lam_n[j], C, Ln[j])
                _k_mtm(C, Cx, T)  # cay(-sig) cay(xi) = cay(sig)^T cay(xi)
                k_cay_inv(T, xp[j])
                for i in range(3):
                    rn[j, i] = r_n[j, i] + dr[b, j, i]
            else:
                _k_mm(Lam_n[j], Cx, T)
                _k_mm(T, C, L1[j])
                _k_mm(Cx, C, T)
                k_cay_inv(T, xp[j])
                for i in range(3):
                    r1[j, i] = r_1[j, i] + dr[b, j, i]
            kv = 0.0 + 0.0j
            kw = 0.0 + 0.0j
            for i in range(3):
                v = (r1[j, i] - rn[j, i]) / h
                kv += v * v
                kw += inertia[i] * xp[j, i] * xp[j, i]
            k[j] = 0.5 * rhoA * kv + 0.5 * kw / (h * h)
        if level == 0:
            k_strains_row(Ln, rn, ds, False, per, Om0, Ga0, spa, spb, sa, sc, T, sd, som)
        else:
            k_strains_row(L1, r1, ds, False, per, Om1, Ga1, spa, spb, sa, sc, T, sd, som)
        for e in range(N):
            W = 0.0 + 0.0j
            gg = 0.0 + 0.0j
            grav = 0.0 + 0.0j
            for i in range(3):
                om = 0.5 * (Om0[e, i] + Om1[e, i])
                ga = 0.5 * (Ga0[e, i] + Ga1[e, i])
                dg = ga - CHI[i]
                W += 0.5 * Jd[i] * om * om + 0.5 * Kd[i] * dg * dg
                gg += ga * ga
                grav += g[i] * 0.5 * (rn[e, i] + r1[e, i] + rn[e + 1, i] + r1[e + 1, i]) * 0.5
            mu = np.sqrt(gg) if paper else 1.0 + 0.0j
            elem[b, e] = h * ds * mu * (0.5 * (k[e] + k[e + 1]) - W + rhoA * grav)
        for j in range(N + 1):
            node[b, j] = 0.0
        fN = 0.0 + 0.0j
        for i in range(3):
            fN += force[i] * 0.5 * (rn[N, i] + r1[N, i])
        node[b, N] = h * fN


# ---------------------------------------------------------------------------
# exact element derivatives (docs/theory.md §9): the element's discrete Lagrangian, its analytic
# gradient with respect to the Lie-group variations of both levels, and the Newton block (the
# derivative of that gradient with respect to the step unknowns) by complex step of the analytic
# gradient.  Every kernel is generic in the scalar type: real for the residual, complex for the
# complex-step columns.
#
# Gradient layout of an element e = (a, b) = (j, j+1): [dr_a, sigma_a, dr_b, sigma_b] (12).


@njit(cache=True, inline="always")
def _k_dcinvT(w, v, s, out):
    """out = (dcay^-1_{s w})^T v = v + (s/2) w x v + (w.v)/4 w   (s = +-1)."""
    wv = 0.25 * (w[0] * v[0] + w[1] * v[1] + w[2] * v[2])
    out[0] = v[0] + 0.5 * s * (w[1] * v[2] - w[2] * v[1]) + wv * w[0]
    out[1] = v[1] + 0.5 * s * (w[2] * v[0] - w[0] * v[2]) + wv * w[1]
    out[2] = v[2] + 0.5 * s * (w[0] * v[1] - w[1] * v[0]) + wv * w[2]


@njit(cache=True)
def k_element(h, ds, rhoA, inertia, Jd, Kd, g, paper, L0a, L0b, r0a, r0b, xia, xib, r1a, r1b, g0, lev_lo, lev_hi, D1, D2,
              M, V):
    """Discrete Lagrangian of one element and its exact gradients; returns (L_e, c), c = h ds mu_e the element's factor.

    ``D1`` (12) receives d/d(dr, sigma) of the level-n variations (level n+1 held), ``D2`` (12) those
    of level n+1 (level n held), layout [dr_a, sigma_a, dr_b, sigma_b].  The level n+1 frames are
    L0 cay(xi).  Only levels lev_lo <= level < lev_hi are computed ((0, 1): D1 only; (1, 2): D2 only).
    ``g0`` = g . o when the four positions are given relative to a point o (0 for absolute positions): the weight's
    potential rhoA g . rm reads the absolute positions, and with the paper's measure its gradient does too (through
    mu, which weights it), so the element's value and gradients are those of the absolute positions in either case.
    All arrays share one scalar type (float64, or complex128 for complex steps);
    ``M`` (5, 3, 3) and ``V`` (16, 3) are scratch of that type.
    """
    Ca, Cb, L1a, L1b, T = M[0], M[1], M[2], M[3], M[4]
    k_cay(xia[0], xia[1], xia[2], Ca)
    k_cay(xib[0], xib[1], xib[2], Cb)
    _k_mm(L0a, Ca, L1a)
    _k_mm(L0b, Cb, L1b)
    om0, om1, pa0, pb0, pa1, pb1, dr0, dr1 = V[0], V[1], V[2], V[3], V[4], V[5], V[6], V[7]
    Gb, Ob, gG, gw, tmp, Ixa, Ixb, tmb = V[8], V[9], V[10], V[11], V[12], V[13], V[14], V[15]
    k_turn(L0a, L0b, T, om0)
    k_turn(L1a, L1b, T, om1)
    for i in range(3):
        dr0[i] = r0b[i] - r0a[i]
        dr1[i] = r1b[i] - r1a[i]
    k_chords(L0a, L0b, dr0, pa0, pb0)
    k_chords(L1a, L1b, dr1, pa1, pb1)
    Gb[0] = 0.0  # (scratch is uninitialised: a zero of the scalar type)
    W = Gb[0]
    gg = Gb[0]
    grav = Gb[0]
    ka = Gb[0]
    kb = Gb[0]
    ih2 = 1.0 / (h * h)
    for i in range(3):
        Gb[i] = k_gamma_mid(pa0[i], pb0[i], pa1[i], pb1[i], ds)
        Ob[i] = 0.5 * (om0[i] + om1[i]) / ds
        dg = Gb[i] - CHI[i]
        W += 0.5 * Jd[i] * Ob[i] * Ob[i] + 0.5 * Kd[i] * dg * dg
        gg += Gb[i] * Gb[i]
        grav += g[i] * 0.25 * (r0a[i] + r1a[i] + r0b[i] + r1b[i])
        va = r1a[i] - r0a[i]
        vb = r1b[i] - r0b[i]
        Ixa[i] = inertia[i] * xia[i]
        Ixb[i] = inertia[i] * xib[i]
        ka += 0.5 * (rhoA * va * va + Ixa[i] * xia[i]) * ih2
        kb += 0.5 * (rhoA * vb * vb + Ixb[i] * xib[i]) * ih2
    P = 0.5 * (ka + kb) - W + rhoA * (grav + g0)
    if paper:
        mu = np.sqrt(gg)
    else:
        mu = 1.0 + 0.0 * gg
    c = h * ds * mu
    # gradients of E = h ds mu P with respect to each level's strains (the same for both levels)
    for i in range(3):
        dg = Gb[i] - CHI[i]
        gG[i] = -0.5 * c * Kd[i] * dg
        if paper:
            gG[i] += h * ds * P * 0.5 * Gb[i] / mu
        gw[i] = -0.5 * h * mu * Jd[i] * Ob[i]  # d/d(omega^l), omega = ds Omega
    for lev in range(lev_lo, lev_hi):
        D = D1 if lev == 0 else D2
        om = om0 if lev == 0 else om1
        sgn = -1.0 if lev == 0 else 1.0
        La = L0a if lev == 0 else L1a
        Lb = L0b if lev == 0 else L1b
        pa = pa0 if lev == 0 else pa1
        pb = pb0 if lev == 0 else pb1
        # the curvature's: sigma_a changes omega by -dcay^-1_om sigma, sigma_b by dcay^-1_{-om} sigma
        _k_dcinvT(om, gw, 1.0, tmp)
        _k_dcinvT(om, gw, -1.0, tmb)
        # the strains' (k_strain_force), the weight rhoA g . rm / 2 per node (rm = (r0 + r1)/2) and the velocities'
        for i in range(3):
            f, sa, sb = k_strain_force(La, Lb, pa, pb, gG, ds, i)
            D[i] = -f + c * (0.25 * rhoA * g[i] + sgn * 0.5 * rhoA * (r1a[i] - r0a[i]) * ih2)
            D[6 + i] = f + c * (0.25 * rhoA * g[i] + sgn * 0.5 * rhoA * (r1b[i] - r0b[i]) * ih2)
            D[3 + i] = sa - tmp[i]
            D[9 + i] = sb + tmb[i]
        # kinetic: level n changes xi by -dcay^-1_xi sigma, level n+1 by dcay^-1_{-xi} sigma
        _k_dcinvT(xia, Ixa, -sgn, tmp)
        for i in range(3):
            D[3 + i] += sgn * 0.5 * c * ih2 * tmp[i]
        _k_dcinvT(xib, Ixb, -sgn, tmp)
        for i in range(3):
            D[9 + i] += sgn * 0.5 * c * ih2 * tmp[i]
    return c * P, c


@njit(cache=True)
def k_rod_gradient(h, ds, rhoA, inertia, Jd, Kd, g, force, paper, Lam_n, r_n, xi, dr, lev_lo, lev_hi, D1, D2, M, V, e1, e2,
                   value):
    """The rod's D1 (level n) and D2 (level n+1) of L_d, (N+1, 6) each: the element kernels (:func:`k_element`) summed,
    and the tip force's node piece; returns the value L_d.  Only the levels lev_lo <= level < lev_hi are written
    ((0, 1): D1 alone, (1, 2): D2 alone; D1 and D2 may then be one array).  The one sum of the rod's element gradients:
    RodPart.gradients, the stepper's rod term (varint.terms.step) and the compiled rod step (varint.schemes.rod_compiled).

    ``dr``: the increments r^{n+1} - r^n (Lambda^n b in the step's chart).  Each element is evaluated in coordinates
    centred on its first node: r_a^n = 0, r_b^n = r_b^n - r_a^n, r_a^{n+1} = dr_a, r_b^{n+1} = (r_b^n - r_a^n) + dr_b
    (docs/theory.md §9, "Momenta to round-off": the gradients depend on positions only through differences; the
    velocities are then the increments themselves, not differences of positions rounded to eps |r|, and Newton can
    meet the momentum balances below that quantum).  The kernel forms node b's velocity as (r_b^{n+1} - r_b^n), which
    rounds it to eps ds; its rounding error delta = dr_b - ((r_b^n - r_a^n + dr_b) - (r_b^n - r_a^n)) is exact in
    floating point, and node b's kinetic rows get c rhoA delta / (2 h^2) (signed as the kernel's), so both nodes' kinetic
    rows read their exact increments.  The weight reads the absolute positions (the paper's measure weights it, so its
    gradient does too): the element kernel takes g . r_a^n with the centred positions (k_element's ``g0``), and the
    value and gradients are those of the absolute positions, for either measure.  ``value``: also sum the value L_d
    (else 0 is returned; the compiled rod step needs the gradients only).  Scratch: M (5, 3, 3), V (20, 3) (the
    element kernel's rows 0-15, the element's positions 16-18), e1, e2 (12)."""
    N = Lam_n.shape[0] - 1
    ih2 = 1.0 / (h * h)
    for j in range(N + 1):
        for i in range(6):
            if lev_lo == 0:
                D1[j, i] = 0.0
            if lev_hi == 2:
                D2[j, i] = 0.0
    za, rb0, rb1 = V[16], V[17], V[18]
    for i in range(3):
        za[i] = 0.0  # (the element kernel's scratch is rows 0-15)
    L = 0.0
    for e in range(N):
        for i in range(3):
            rb0[i] = r_n[e + 1, i] - r_n[e, i]
            rb1[i] = rb0[i] + dr[e + 1, i]
        # the weight's potential at the absolute positions: in the value, and through mu in the paper measure's gradient
        g0 = g[0] * r_n[e, 0] + g[1] * r_n[e, 1] + g[2] * r_n[e, 2] if (value or paper) else 0.0
        val, c = k_element(h, ds, rhoA, inertia, Jd, Kd, g, paper, Lam_n[e], Lam_n[e + 1], za, rb0, xi[e], xi[e + 1],
                           dr[e], rb1, g0, lev_lo, lev_hi, e1, e2, M, V)
        if value:
            L += val
        cr = c * 0.5 * rhoA
        for i in range(3):
            k = cr * (dr[e + 1, i] - (rb1[i] - rb0[i])) * ih2  # node b's rounding error, exact in floating point
            e1[6 + i] -= k
            e2[6 + i] += k
        for i in range(6):
            if lev_lo == 0:
                D1[e, i] += e1[i]
                D1[e + 1, i] += e1[6 + i]
            if lev_hi == 2:
                D2[e, i] += e2[i]
                D2[e + 1, i] += e2[6 + i]
    for i in range(3):
        if lev_lo == 0:
            D1[N, i] += 0.5 * h * force[i]
        if lev_hi == 2:
            D2[N, i] += 0.5 * h * force[i]
        if value:
            L += 0.5 * h * force[i] * (r_n[N, i] + (r_n[N, i] + dr[N, i]))
    return L


@njit(cache=True)
def _k_rod_gradient(h, ds, rhoA, inertia, Jd, Kd, g, force, paper, Lam_n, r_n, xi, dr, lev_lo, lev_hi, D1, D2):
    """:func:`k_rod_gradient` with its scratch (RodPart.gradients)."""
    return k_rod_gradient(h, ds, rhoA, inertia, Jd, Kd, g, force, paper, Lam_n, r_n, xi, dr, lev_lo, lev_hi, D1, D2,
                          np.empty((5, 3, 3)), np.empty((20, 3)), np.empty(12), np.empty(12), True)


@njit(cache=True)
def _element_scratch():
    """Complex work arrays of one :func:`k_element` call: (M, V, D1, D2, Lambda_a, Lambda_b)."""
    c = np.complex128
    return (np.empty((5, 3, 3), c), np.empty((16, 3), c), np.empty(12, c), np.empty(12, c),
            np.empty((3, 3), c), np.empty((3, 3), c))


@njit(cache=True, inline="always")
def k_chart_column(Lam_n, xi, r_1, e, k, eps, xa, xb, qa, qb):
    """Element e's level-(n+1) chart in the step unknowns u = (b_a, xi_a, b_b, xi_b), column k moved by i eps:
    xi of its two nodes into xa, xb and r_1 into qa, qb (a b-column moves r_1 along the level-n frame's
    column d, since r_1 = r_n + Lambda_n b).  Shared by the Newton blocks of every rod kernel."""
    for i in range(3):
        xa[i] = xi[e, i]
        xb[i] = xi[e + 1, i]
        qa[i] = r_1[e, i]
        qb[i] = r_1[e + 1, i]
    d = k % 3
    if k < 3:
        for i in range(3):
            qa[i] += 1j * eps * Lam_n[e, i, d]
    elif k < 6:
        xa[d] += 1j * eps
    elif k < 9:
        for i in range(3):
            qb[i] += 1j * eps * Lam_n[e + 1, i, d]
    else:
        xb[d] += 1j * eps


@njit(cache=True, inline="always")
def k_body_rows(Lam_n, e, col, out):
    """out = an element's 12 derivative rows ``col`` with each node's translational rows rotated into its
    level-n body frame (the rows of the step residual)."""
    for i in range(3):
        out[i] = Lam_n[e, 0, i] * col[0] + Lam_n[e, 1, i] * col[1] + Lam_n[e, 2, i] * col[2]
        out[6 + i] = Lam_n[e + 1, 0, i] * col[6] + Lam_n[e + 1, 1, i] * col[7] + Lam_n[e + 1, 2, i] * col[8]
        out[3 + i] = col[3 + i]
        out[9 + i] = col[9 + i]


@njit(cache=True, inline="always")
def k_load_element(Lam, r, e, La, Lb, ra, rb):
    """Element e's frames and positions copied into La, Lb, ra, rb (the complex steps' scratch)."""
    for i in range(3):
        ra[i] = r[e, i]
        rb[i] = r[e + 1, i]
        for m in range(3):
            La[i, m] = Lam[e, i, m]
            Lb[i, m] = Lam[e + 1, i, m]


@njit(cache=True, inline="always")
def _k_config_column(Lam, r, e, k, eps, La, Lb, ra, rb, C, Lc, w):
    """Element e's configuration (frames La, Lb, positions ra, rb) with column k of z = (dr_a, sigma_a, dr_b,
    sigma_b) moved by i eps: r -> r + i eps e_d, or Lambda -> Lambda cay(i eps e_d).  Shared by the static
    (both-level) blocks."""
    k_load_element(Lam, r, e, La, Lb, ra, rb)
    d = k % 3
    if k < 3:
        ra[d] += 1j * eps
    elif 6 <= k < 9:
        rb[d] += 1j * eps
    else:  # sigma of node a (k < 6) or b
        w[:] = 0.0
        w[d] = 1j * eps
        k_cay(w[0], w[1], w[2], C)
        node = e if k < 6 else e + 1
        for i in range(3):
            for m in range(3):
                Lc[i, m] = Lam[node, i, m]
        _k_mm(Lc, C, La if k < 6 else Lb)


@njit(cache=True)
def k_step_block(h, ds, rhoA, inertia, Jd, Kd, g, paper, Lam_n, r_n, xi, r_1, e, mask, eps, cs, col, out):
    """Element e's Newton block of the step residual: out[:, k] = d(rotated D1 of element e)/d u_k (12 x 12), u = (b_a,
    xi_a, b_b, xi_b), r_1 = r_n + Lambda_n b, by complex step of the analytic gradient (``k_element`` in the chart of
    ``k_chart_column``; the translational rows in the level-n body frames, ``k_body_rows``): exact to round-off.
    Columns of unknowns off the ``mask`` (N+1, 6) are zero.  ``cs``: complex scratch (M, V, e1, e2, La, Lb, ra, rb, xa,
    xb, qa, qb; ``_element_scratch`` and six 3-vectors), ``col`` (12) real scratch.  The one block of the stepper's
    Jacobian (``_k_step_blocks``) and of the compiled rod step's exact band Jacobian (varint.schemes.rod_compiled)."""
    M, V, e1, e2, La, Lb = cs[0], cs[1], cs[2], cs[3], cs[4], cs[5]
    ra, rb, xa, xb, qa, qb = cs[6], cs[7], cs[8], cs[9], cs[10], cs[11]
    inv = 1.0 / eps
    k_load_element(Lam_n, r_n, e, La, Lb, ra, rb)
    for k in range(12):
        if not mask[e + k // 6, k % 6]:
            for i in range(12):
                out[i, k] = 0.0
            continue
        k_chart_column(Lam_n, xi, r_1, e, k, eps, xa, xb, qa, qb)
        k_element(h, ds, rhoA, inertia, Jd, Kd, g, paper, La, Lb, ra, rb, xa, xb, qa, qb, 0.0, 0, 1, e1, e2, M, V)
        for i in range(12):
            col[i] = e1[i].imag * inv
        k_body_rows(Lam_n, e, col, out[:, k])


@njit(cache=True)
def _k_step_blocks(h, ds, rhoA, inertia, Jd, Kd, g, paper, Lam_n, r_n, xi, r_1, mask, eps, blocks):
    """Newton blocks of the step residual: blocks[e] = :func:`k_step_block` of element e.

    u = (b_a, xi_a, b_b, xi_b), r_1 = r_n + Lambda_n b; the translational rows are in the level-n body
    frame of their node (as the stepper's residual rows: varint.terms.step.RodElements).  By complex step of the analytic
    gradient: exact to round-off.  Columns of unknowns off the ``mask`` (N+1, 6) are left zero.
    """
    N = Lam_n.shape[0] - 1
    c = np.complex128
    M, V, e1, e2, La, Lb = _element_scratch()
    cs = (M, V, e1, e2, La, Lb, np.empty(3, c), np.empty(3, c), np.empty(3, c), np.empty(3, c), np.empty(3, c),
          np.empty(3, c))
    col = np.empty(12)
    for e in range(N):
        k_step_block(h, ds, rhoA, inertia, Jd, Kd, g, paper, Lam_n, r_n, xi, r_1, e, mask, eps, cs, col, blocks[e])


@njit(cache=True)
def _k_static_blocks(ds, rhoA, inertia, Jd, Kd, g, paper, Lam, r, mask, eps, blocks):
    """Blocks of d(-grad U)/dz: blocks[e, :, k] = d(D1 + D2 of element e at h = 1, xi = 0)/d z_k under
    z = (dr_a, sigma_a, dr_b, sigma_b), Lambda -> Lambda cay(sigma), r -> r + dr (both levels).
    By complex step of the analytic gradient: exact to round-off.  Columns off the ``mask`` are left zero."""
    N = Lam.shape[0] - 1
    c = np.complex128
    M, V, e1, e2, La, Lb = _element_scratch()
    C = np.empty((3, 3), c)
    ra = np.empty(3, c)
    rb = np.empty(3, c)
    zero = np.zeros(3, c)
    w = np.zeros(3, c)
    Lc = np.empty((3, 3), c)  # the node's frame, complex, for the sigma columns
    inv = 1.0 / eps
    for e in range(N):
        for k in range(12):
            if not mask[e + k // 6, k % 6]:
                for i in range(12):
                    blocks[e, i, k] = 0.0
                continue
            _k_config_column(Lam, r, e, k, eps, La, Lb, ra, rb, C, Lc, w)
            k_element(1.0, ds, rhoA, inertia, Jd, Kd, g, paper, La, Lb, ra, rb, zero, zero, ra, rb, 0.0, 0, 2, e1, e2, M, V)
            for i in range(12):
                blocks[e, i, k] = (e1[i].imag + e2[i].imag) * inv


@njit(cache=True, inline="always", error_model="numpy")
def k_measure(e, ds, Lam_n, r_n, xi, dr, A, B, C):
    """The paper's measure mu_e = |Gamma_bar_e| of element e at the step's chart (the level-n frames Lam_n and
    positions r_n, the turns xi and increments dr): the element kernel's own (k_element's midpoint strain of the
    centred element of k_rod_gradient, the same arithmetic to the bit).  A, B, C: (3, 3) scratch."""
    k_cay(xi[e, 0], xi[e, 1], xi[e, 2], C)
    _k_mm(Lam_n[e], C, A)
    k_cay(xi[e + 1, 0], xi[e + 1, 1], xi[e + 1, 2], C)
    _k_mm(Lam_n[e + 1], C, B)
    d0, d1 = C[0], C[1]
    for k in range(3):
        d0[k] = r_n[e + 1, k] - r_n[e, k]
        d1[k] = (d0[k] + dr[e + 1, k]) - dr[e, k]
    gg = 0.0
    for i in range(3):
        gi = k_gamma_mid(k_body(Lam_n[e], d0, i), k_body(Lam_n[e + 1], d0, i), k_body(A, d1, i), k_body(B, d1, i), ds)
        gg += gi * gi
    return math.sqrt(gg)
