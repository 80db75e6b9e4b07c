"""The energy-momentum step for the rod alone (``time.scheme = "energy-momentum"``; docs/theory.md §12a).

The midpoint Lie-group step of §9 resonates with its unresolved shear-rotation, axial and torsional modes on stiff
nonlinear motion (§12).  This step conserves the total energy to the solver tolerance and the linear and angular
momenta to round-off at any step, which bounds the stiff amplitudes (the potential is coercive): the
energy-momentum idea of Simo & Tarnow (1992) and Simo, Tarnow & Doblaré (1995), here in the director ("rotationless")
form of Betsch & Steinmann (2002) and Romero & Armero (2002) with a discrete gradient (Gonzalez 1996) of the rod's
own potential.

Unknowns per node: r_j and the frame Lambda_j = [d_1 d_2 d_3] as three directors in R^3 (the configuration lives in
R^{12(N+1)}, where rotations act linearly), with the six orthonormality constraints g = d_i.d_j - delta_ij held by
multipliers.  The kinetic energy is exactly the rod's, 1/2 m |r'|^2 + 1/2 W.I W = 1/2 m |r'|^2 + 1/2 sum_i E_i |d_i'|^2
with E_i = tr(I)/2 - I_i (the Euler tensor; for the rod's I = rho diag(2I, I, I): E = (0, rho I, rho I)).
The potential is the rod's (§9) with the directors in place of Lambda:
Gamma_e = 1/2 (D_a + D_b)^T (r_b - r_a)/ds and Omega_e = cay^-1(D_a^T D_b)/ds = (2/ds) a/c with
a = axial(R - R^T), c = 1 + tr R, R = D_a^T D_b.  The step (h, levels 0 -> 1, midpoint quantities with a bar):

    M (v_1 - v_0) = -h ( grad_d U(q_0, q_1) + G(q_bar)^T lambda ),   q_1 - q_0 = h (v_0 + v_1)/2,   g(q_1) = 0,

grad_d U the strain-space discrete gradient: the stresses at the mean of the two levels' strains times a strain
"B-matrix" that maps q_1 - q_0 exactly onto the strain changes (Gamma and R are bilinear, so their midpoint
derivatives are exact; Omega = 2a/(c ds) uses a_1/c_1 - a_0/c_0 = (c_bar da - a_bar dc)/(c_0 c_1)).  Hence
U(q_1) - U(q_0) = grad_d U . (q_1 - q_0) identically (for any q_0, q_1, not only orthonormal frames), g quadratic
gives g(q_1) - g(q_0) = G(q_bar)(q_1 - q_0), and the kinetic energy changes by v_bar . M dv = -dU: energy conserved
to the solver's residual.  Every piece is invariant under r -> Q r + c, D -> Q D for all Q in O(3) acting linearly,
so the midpoint-evaluated gradients annihilate the rigid directions at q_bar: P and J = sum r x m v + d_i x E_i d_i'
are conserved to round-off (without loads: gravity and a tip force change P by exactly h sum f, a tip torque J by
exactly h T per step).

Scope in this version: the rod alone, free, pinned or clamped ends, gravity and a dead tip force (potentials linear
in r: their discrete gradient is exact), shearable or with rod.constraint (Gamma = chi held at the levels by element
forces mu); a dead tip torque (its work summed: E - work is conserved, J changes by exactly h T per step); runs
resume from checkpoints (state_data).  No fluid or wall (varint/schemes/em_tube.py has them), paper measure or periodic ends
(the scene check refuses them in one line).  The default remains the midpoint scheme.  The momenta are kept to
round-off by increments as unknowns and a rigid polish after Newton (docs/theory.md §12a, "Momenta to round-off").
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..errors import SolverError
from .base import MAX_HALVINGS
from ..lattice.lie import hat, k_hat
from ..terms.rod import CHI, k_gamma, k_strains_row, k_turn, level_strains, origin_shift

_PAIRS = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))
NV = 18  # unknowns per node: r (3), D (9, row-major Lambda), lambda (6)
NC = 3  # with rod.constraint: the element forces mu_e (Gamma_e = chi), kept in the block of the element's first node


def supports(model):
    """None when the energy-momentum step (this module's rod, varint/schemes/em_tube.py's coupled tube) covers
    ``model``, else a one-line reason naming the key (the scheme's ``supports``: varint/schemes/energy_momentum.py)."""
    rod, t, sc = model.rod, model.tube, model.scene
    if rod is None:
        return straight_tube_supports(model)
    if t is not None and not t.has_fluid:
        return "time.scheme: 'energy-momentum' needs a [fluid] with a [wall] on a [rod]"
    if t is not None and t.open_ends:
        return "time.scheme: 'energy-momentum' covers closed fluid ends only in this version (fluid.ends)"
    if t is not None and t.periodic:
        return "time.scheme: 'energy-momentum' covers closed fluid ends only in this version (fluid.ends)"
    if rod.periodic:
        return "time.scheme: 'energy-momentum' does not cover periodic rod ends in this version (rod.ends)"
    if sc.shock_capturing is not None and sc.shock_capturing.limiter != "none":
        return ("shock_capturing.limiter: the energy-momentum scheme takes the viscosity without a limiter in this "
                "version (limiter = 'none')")
    if rod.paper_measure:
        return "time.scheme: 'energy-momentum' needs rod.measure = 'reference'"
    if t is not None and any(type(f).__name__ != "CoupledShockCapturing" for f in t.forces):
        return ("time.scheme: 'energy-momentum' does not cover this non-conservative force on the fluid in this "
                "version")
    return None


def straight_tube_supports(model):
    """The straight tube's energy-momentum step (the midpoint step with discrete-gradient pressures, docs/theory.md
    §12d): None where it is built, else the reason naming the key."""
    t = model.tube
    if t.eos is None:
        return ("time.scheme: 'energy-momentum' on the straight tube needs a compressible fluid (fluid.model = "
                "'ideal-gas' or 'barotropic'): an incompressible liquid's volumes would have to be held at the levels "
                "with the discrete-gradient volumes as the constraint's force (docs/theory.md §12d); it runs 'midpoint'")
    if t.has_wall and not t.wall_dynamic:
        return ("time.scheme: 'energy-momentum' needs a rigid or a dynamic wall on the straight tube: a quasistatic "
                "wall's radii are half-level unknowns of the midpoint step (wall.model)")
    if t.open_ends and (t.has_wall or not t.duct.uniform):
        return ("time.scheme: 'energy-momentum' with open fluid ends (fluid.ends) needs a rigid uniform tube in this "
                "version (its volumes linear in the labels; a [wall] or tube.area_table would need their discrete "
                "gradients on the moving lattice, docs/theory.md §12d)")
    return None


#: varint.lattice.lie.hat under the name the step classes' constructors (here and in em_tube) and rigid_correction read
_hat = hat


def _T(A):
    return np.swapaxes(A, -1, -2)


def strains(r, D, ds):
    """Element strains of the director configuration (any D, orthonormal or not; leading batch axes, real or complex):
    Omega, Gamma, and a, c of Omega = (2/ds) a/c (varint.terms.rod.level_strains, the rod's own)."""
    st = level_strains(D, r, ds)
    return st.Omega, st.Gamma, st.a, st.c


def potential(r, D, ds, Jd, Kd):
    """U = sum_e ds (1/2 Omega.J Omega + 1/2 (Gamma - chi).K (Gamma - chi)) (docs/theory.md §9)."""
    Om, Ga, _, _ = strains(r, D, ds)
    dG = Ga - CHI
    return ds * np.sum(0.5 * np.sum(Jd * Om * Om, -1) + 0.5 * np.sum(Kd * dG * dG, -1), -1)


def discrete_gradient(r0, D0, r1, D1, ds, Jd, Kd, mu=None):
    """grad_d U(q_0, q_1) = (F_r (.., N+1, 3), F_D (.., N+1, 3, 3)) with
    U(q_1) - U(q_0) = sum F_r . (r_1 - r_0) + F_D : (D_1 - D_0) identically (docs/theory.md §12a); leading batch axes
    broadcast, real or complex (the compiled :func:`rod_discrete_gradient`, :func:`k_dg_row` on each row).

    With ``mu`` (.., N, 3), the element forces of rod.constraint, also the constraint's force
    ds G_Gamma(q_bar)^T mu (Gamma is bilinear: its midpoint derivative maps q_1 - q_0 exactly onto Gamma_1 - Gamma_0,
    so this force does no work when both levels hold Gamma = chi): it enters exactly as a stress added to n."""
    r0, D0, r1, D1 = (np.asarray(x) for x in (r0, D0, r1, D1))
    mu = None if mu is None else np.asarray(mu)
    n = r1.shape[-2]
    dt = np.result_type(r0, D0, r1, D1, np.float64, *(() if mu is None else (mu,)))
    level_batch = np.broadcast_shapes(r0.shape[:-2], D0.shape[:-3])
    batch = np.broadcast_shapes(level_batch, r1.shape[:-2], D1.shape[:-3], *(() if mu is None else (mu.shape[:-2],)))

    def rows(x, b, tail):
        return np.ascontiguousarray(np.broadcast_to(x, b + tail), dtype=dt).reshape((-1,) + tail)

    lb = batch if level_batch else ()  # a level without batch axes is read by every row, not copied
    stress = np.zeros(batch + (n - 1, 3), dt) if mu is None else mu
    B = int(np.prod(batch, dtype=int))
    Fr, FD = np.empty((B, n, 3), dt), np.empty((B, n, 3, 3), dt)
    rod_discrete_gradient(rows(r0, lb, (n, 3)), rows(D0, lb, (n, 3, 3)), rows(r1, batch, (n, 3)),
                          rows(D1, batch, (n, 3, 3)), float(ds), np.asarray(Jd, dtype=np.float64),
                          np.asarray(Kd, dtype=np.float64), rows(stress, batch, (n - 1, 3)), Fr, FD)
    return Fr.reshape(batch + (n, 3)), FD.reshape(batch + (n, 3, 3))


def body_angular_velocity(D, V):
    """W_j from the massive directors' velocities: Lambda^T d_i' = W x e_i for i = 2, 3 (d_1 carries no inertia,
    E_1 = 0, so its velocity is not a dynamical quantity)."""
    A = _T(D) @ V
    return np.stack([0.5 * (A[:, 2, 1] - A[:, 1, 2]), A[:, 0, 2], -A[:, 0, 1]], -1)


def rigid_correction(h, P, J, m, x, E, Db):
    """(a, w) of the rigid correction that zeroes the momentum balances (P, J) of a step (docs/theory.md §12a, "Momenta
    to round-off"): the 6x6 locked-inertia system [[M I, -S^], [S^, I_lock]] (a, w) = -(h/2) (P, J) for point masses
    ``m`` at the midpoint positions ``x`` and directors ``Db`` (.., 3, 3) with masses ``E``; the caller moves each point
    by a + w x x and each director by w x d."""
    eye = np.eye(3)
    S = (m[:, None] * x).sum(0)
    Ilock = np.einsum("n,nk,nl->kl", m, x, x)
    Ilock = eye * np.trace(Ilock) - Ilock
    d = np.swapaxes(Db, 1, 2)  # d[n, i] = director i of node n
    Id = np.einsum("ni,nik,nil->kl", E, d, d)
    Ilock += eye * np.trace(Id) - Id
    A = np.zeros((6, 6))
    A[:3, :3] = m.sum() * eye
    A[:3, 3:] = -_hat(S)
    A[3:, :3] = _hat(S)
    A[3:, 3:] = Ilock
    aw = np.linalg.solve(A, -(0.5 * h) * np.concatenate([P, J]))
    return aw[:3], aw[3:]


def tip_torque_forces(Db, torque):
    """The director forces F_i = w x dbar_i (.., 3, 3; column i) of a dead torque T at a node whose mean directors are
    the columns of Db, with (tr M I - M) w = T, M = Db Db^T, so that sum_i dbar_i x F_i = T exactly: the step's angular
    momentum changes by exactly h T, and the energy by the work sum_i F_i . (d_i^1 - d_i^0) (docs/theory.md §12a,
    "A dead tip torque").  Complex-safe (the Jacobian's complex steps pass through the 3x3 solve)."""
    M = Db @ np.swapaxes(Db, -1, -2)
    A = np.trace(M, axis1=-2, axis2=-1)[..., None, None] * np.eye(3) - M
    w = np.linalg.solve(A, np.broadcast_to(torque, A.shape[:-1])[..., None])[..., 0]
    return np.swapaxes(np.cross(w[..., None, :], np.swapaxes(Db, -1, -2)), -1, -2)


#: full Newton keeps its factorisation (chord iterations, refreshed on slow contraction) once its update is below this:
#: there the Jacobian of the last iterate contracts as fast as a fresh one would, at no Jacobian's cost
FULL_NEWTON_TO = 1e-3
#: full Newton gives up on a start once an update exceeds this multiple of its smallest one (at least 1e-2): it may
#: grow before it converges, but by this much it has left the solution's basin and iterating on to max_iter costs a
#: Jacobian per iteration (the tumbling rod at 10 ms: 40-iteration failures, most of its Jacobians)
DIVERGED = 1e4


def chord_newton(step, z, chord, residual, factor, update, size_of, domain_problem=None):
    """Newton from z for an energy-momentum step (RodEMStep, varint.schemes.em_tube.TubeEMStep): chord iterations on the kept
    factorisation ``step._lu`` (``factor(z)`` makes one; refreshed when the contraction is slower than
    ``step.rate_refresh`` or after 20 chord iterations; a fresh one that does not contract ends the attempt), or full
    Newton (``chord=False``: a fresh Jacobian every iteration; the update may grow before it converges).  Iterates to
    the round-off floor: after the update ``size_of(dz)`` falls below ``step.tol`` it stops when the next update no
    longer shrinks.  ``domain_problem(z)``: why an iterate cannot be evaluated, or None.  Returns (z, iterations)."""
    last = np.inf
    smallest = np.inf  # the smallest update so far (full Newton's divergence test)
    fresh = False
    stale = 0  # chord iterations since the factorisation was made
    n1 = step.n + 1
    for it in range(1, step.max_iter + 1):
        why = domain_problem(z) if domain_problem is not None else None
        if why:  # an iterate outside the domain: its residual means nothing (and may be singular)
            raise SolverError(f"step {n1}: Newton's iterate {why}; try a smaller time.step")
        R = residual(z)
        step.stats["residuals"] += 1
        if not np.all(np.isfinite(R)):
            raise SolverError(f"step {n1}: non-finite residual")
        if step._lu is None or not (chord or last < FULL_NEWTON_TO):
            step._lu = None
            step._lu = factor(z)
            fresh, stale = True, 0
        stale += 1
        dz = update(R)
        size = size_of(dz)
        if not np.isfinite(size):
            raise SolverError(f"step {n1}: singular Newton matrix")
        if size >= last and last < 1e3 * step.tol:
            if last > step.tol and chord and not fresh:
                step._lu = None  # a stale factorisation stalls above the tolerance: refresh it before calling it the floor
                last = np.inf
                continue
            return z, it  # round-off floor reached: the update no longer shrinks
        if size > last and fresh and chord:
            raise SolverError(f"step {n1}: Newton diverges (update {last:.2e} -> {size:.2e})")
        smallest = min(smallest, size)
        if not chord and size > DIVERGED * max(smallest, 1e-2):  # full Newton left its basin: the next start instead
            raise SolverError(f"step {n1}: Newton diverges (update {smallest:.2e} -> {size:.2e})")
        z = z + dz
        if size < 1e-3 * step.tol:
            return z, it
        if (chord or last < FULL_NEWTON_TO) and it > 1 and not fresh and last >= step.tol and (
                size > step.rate_refresh * last or stale >= 20):
            step._lu = None  # slow contraction, or 20 chord iterations on one factorisation: refresh the Jacobian
        fresh = False
        last = size
    if last < 1e3 * step.tol:
        return z, step.max_iter
    raise SolverError(f"step {n1}: Newton did not converge in {step.max_iter} iterations (update {last:.2e})")




def em_step(step, starts):
    """One step of an energy-momentum scheme (:meth:`RodEMStep.step`, :meth:`varint.schemes.em_tube.TubeEMStep.step`): chord
    Newton from ``step._predict()``; on failure full Newton from each of ``starts`` in turn; if all fail,
    :func:`halved_step`.  Sets ``step.last`` (iterations and Jacobians of the whole step; ``fallback`` 0: none, 1: a
    full-Newton restart, 2: solved from two half steps) and returns the iterations."""
    jac0, it0, n0 = step.stats["jacobians"], step.stats["iterations"], step.n
    fallback, z = 0, None
    try:
        z, it = step._solve(step._predict(), chord=True)
    except SolverError as exc:
        if step._halvings == 0:  # the half steps' own fallbacks are not counted again
            step.stats["fallbacks"] = step.stats.get("fallbacks", 0) + 1
        fallback = 1
        for start in starts:
            step._lu = None
            try:
                z, it = step._solve(start(), chord=False)
                break
            except SolverError as e:
                exc = e
        if z is None:
            step._lu = None
            halved_step(step, exc)
            fallback = 2
    if z is not None:
        step._advance(z, it)
    step.n = n0 + 1
    it = step.stats["iterations"] - it0
    step.last = dict(iterations=it, jacobians=step.stats["jacobians"] - jac0, fallback=fallback)
    return it


def halved_step(step, exc):
    """Newton failed at step ``step.h`` from every start (``exc`` its error): take the step as two steps of h/2 from
    the same level (each with all of its own fallbacks, halved again up to :data:`MAX_HALVINGS` times), use the level
    they reach as the start of full Newton at h, and keep Newton's solution if it converges; otherwise keep the two
    half steps.  Either way energy and momenta are conserved as on any step (the identities of theory §12a hold at
    every step size); the first keeps the fixed-step map, the second composes two steps of the same scheme
    (docs/theory.md §12c: where Newton at h fails, why, and how often).

    ``step`` is a :class:`RodEMStep` or :class:`varint.schemes.em_tube.TubeEMStep`: it has ``state_data``/``restore``,
    ``_solve``, ``_guess_over(before)`` (the unknowns over h from the level in ``before`` to its current level),
    ``_prev_of(z)`` (the predictor's data for increments z) and ``_advance(z, it)``.  When even h/2**MAX_HALVINGS
    fails (or anything else is raised) the step is back at its level; a failure raises a SolverError with ``exc``'s
    message.  ``stats["halvings"]`` counts the steps solved this way, ``stats["halved_steps"]`` those kept as two
    half steps (the outermost step only, however deep the halving went)."""
    if step._halvings >= MAX_HALVINGS:
        raise exc
    n0, h, before = step.n, step.h, step.state_data()
    step._halvings += 1
    step.h = 0.5 * h
    step.restore(before, n0)
    step._prev = None  # the half step's predictor: a rigid motion at the level's velocities
    try:
        step.step()
        step.step()
    except SolverError:
        halves_ok = False
    except BaseException:  # an interrupt or an unexpected error: back to the level before passing it on
        step.restore(before, n0)
        raise
    else:
        halves_ok = True
    finally:
        step.h = h
        step._halvings -= 1
    outermost = step._halvings == 0
    if not halves_ok:  # back to the level the step started from, and the step's own message
        step.restore(before, n0)
        if outermost:
            raise SolverError(f"{exc} (and with the step halved {MAX_HALVINGS} times)") from None
        raise exc
    if outermost:
        step.stats["halvings"] = step.stats.get("halvings", 0) + 1
    after, guess = step.state_data(), step._guess_over(before)
    step.restore(before, n0)
    try:
        z, it = step._solve(guess, chord=False)
    except SolverError:
        if outermost:
            step.stats["halved_steps"] = step.stats.get("halved_steps", 0) + 1
        step.restore(after, n0 + 1)  # the two half steps are the step
        step._prev = step._prev_of(guess)  # the next step's predictor: the increment over h (rigid motion is poor)
        return
    step._advance(z, it)


def director_masses(rod):
    """Node masses m_j and director masses E_ji = w_j (tr I / 2 - I_i) of the rod's lumped kinetic metric."""
    I = rod.section.inertia
    return rod.node_mass.copy(), rod.w[:, None] * (0.5 * I.sum() - I)[None, :]


class RodEMStep:
    """Energy-momentum stepping of a rod alone (docs/theory.md §12a); its own state (r, D, v, V, lambda, mu)."""

    def __init__(self, model, h, tol=1e-13, max_iter=40):
        why = supports(model)
        if why:
            raise SolverError(why)
        rod = model.rod
        self.rod, self.h, self.tol, self.max_iter = rod, float(h), tol, max_iter
        self.N, self.ds = rod.N, rod.ds
        #: rod.constraint: Gamma_e = chi held at the levels by element forces mu_e (docs/theory.md §12a, "The
        #: inextensible rod"); the stretch-shear energy is then absent (K = 0), as in the midpoint's §9a
        self.constrained = bool(rod.constrained)
        self.nv = NV + NC * self.constrained
        self.Jd = rod.section.J
        self.Kd = np.zeros(3) if self.constrained else rod.section.K
        self.m, self.E = director_masses(rod)
        self.r = rod.r0.copy()
        self.D = rod.Lam0.copy()
        # a held node neither moves nor turns, whatever rod.initial says (as the midpoint's initial momenta)
        self.v = rod.v0 * rod.mask[:, :3]
        W = rod.omega0 * rod.mask[:, 3:]  # body angular velocity: d_i' = Lambda (W x e_i)
        self.V = np.einsum("nij,njk->nik", self.D, _hat(W) @ np.eye(3))
        self.lam = np.zeros((self.N + 1, 6))
        self.mu = np.zeros((self.N + 1, NC))  # node N's entry is no element's: held at zero
        if self.constrained:
            miss = float(np.max(np.abs(strains(self.r, self.D, self.ds)[1] - CHI)))
            if miss > 1e-9:
                raise SolverError(f"rod.constraint: the initial configuration misses Gamma = chi by {miss:.1e}")
        # conservative loads, linear in r (their discrete gradient is exact): gravity on the lumped masses, the dead
        # tip force; U_ext = -sum f_j . r_j
        self.fext = self.m[:, None] * rod.g[None, :]
        self.fext[-1] += rod.force
        # a dead tip torque T (not conservative): director forces at node N with sum_i dbar_i x F_i = T exactly
        # (tip_torque_forces); its work is summed in self.work, so that E - work is the conserved quantity
        self.torque = np.asarray(rod.torque, dtype=float)
        self.has_torque = bool(np.any(self.torque))
        self.work = 0.0
        # supports: a pinned node keeps r (its rows become r_1 - r_0 = 0), a clamped one also its directors and its
        # orthonormality multipliers (its orthonormality then holds by itself; its element's mu stays free)
        self.fixed = np.zeros((self.N + 1, self.nv), dtype=bool)
        for node, kind in ((0, model.scene.rod.ends.s0), (self.N, model.scene.rod.ends.sL)):
            if kind in ("pinned", "clamped"):
                self.fixed[node, :3] = True
            if kind == "clamped":
                self.fixed[node, 3:NV] = True
        self.fixed[self.N, NV:] = True
        self.free = not np.any(self.fixed[:, :NV])
        self.fixed = self.fixed.ravel()
        # a free rod travels: r is kept relative to a floating origin o moved with node 0 after each step by an exact
        # grid shift (varint.terms.rod.origin_shift), so the rounding of r is eps times the rod's size, not eps times its
        # distance from the start (docs/theory.md §12c; as TubeEMStep and the midpoint's FastRodStep)
        self.floating_origin = self.free
        self.origin = np.zeros(3)
        # Newton's update size: positions relative to L, director components as they are, on the q unknowns only
        self._qmask = np.tile(np.arange(self.nv) < 12, self.N + 1)
        self._update_scale = np.tile(np.concatenate([np.full(3, rod.L), np.ones(9)]), self.N + 1)
        self.n = 0
        self.last = dict(iterations=0, jacobians=0, fallback=0)
        self._lu = None
        self._plan = None
        self._prev = None
        self.rate_refresh = 0.5
        #: the compiled residual (``_k_residual``) for the iterations and the Jacobian; False: the numpy reference
        self.compiled = True
        self.stats = dict(iterations=0, jacobians=0, residuals=0)
        self._halvings = 0  # depth of halved_step's recursion

    # -- the step's equations ---------------------------------------------------------------------------

    def _unpack(self, z):
        """(dr, dD, lambda) of z; :meth:`_mu` gives the constraint's element forces."""
        z = z.reshape(z.shape[:-1] + (self.N + 1, self.nv))
        return z[..., :3], z[..., 3:12].reshape(z.shape[:-1] + (3, 3)), z[..., 12:NV]

    def _mu(self, z):
        """mu_e (.., N, 3) of z, or None without rod.constraint."""
        if not self.constrained:
            return None
        return z.reshape(z.shape[:-1] + (self.N + 1, self.nv))[..., :-1, NV:]

    def residual(self, z):
        """R(z) (.., (N+1)*nv) of the step from the current level; z = (r_1 - r_0, D_1 - D_0, lambda) per node: the
        unknowns are the increments, so that the level velocities v_1 = 2 dr/h - v_0 carry no rounding of the
        positions (docs/theory.md §12a, "Momenta to round-off")."""
        h = self.h
        dr, dD, lam = self._unpack(z)
        r1, D1 = self.r + dr, self.D + dD
        mu = self._mu(z)
        Fr, FD = discrete_gradient(self.r, self.D, r1, D1, self.ds, self.Jd, self.Kd, mu)
        Db = 0.5 * (self.D + D1)
        S = np.stack([np.stack([2 * lam[..., 0], lam[..., 3], lam[..., 4]], -1),
                      np.stack([lam[..., 3], 2 * lam[..., 1], lam[..., 5]], -1),
                      np.stack([lam[..., 4], lam[..., 5], 2 * lam[..., 2]], -1)], -2)
        Rr = (2.0 / h) * self.m[:, None] * (dr - h * self.v) + h * Fr
        RD = (2.0 / h) * self.E[:, None, :] * (dD - h * self.V) + h * (FD + Db @ S)
        C = _T(D1) @ D1
        Rl = np.stack([C[..., i, j] - (1.0 if i == j else 0.0) for i, j in _PAIRS], -1)
        parts = [Rr, RD.reshape(RD.shape[:-2] + (9,)), Rl]
        if mu is not None:  # the rows Gamma_e(q_1) - chi at element e's first node; node N's rows are replaced below
            Rc = np.zeros(Rr.shape, dtype=np.result_type(Rr, mu))
            Rc[..., :-1, :] = strains(r1, D1, self.ds)[1] - CHI
            parts.append(Rc)
        out = np.concatenate(parts, -1)
        out = out.reshape(out.shape[:-2] + (-1,))
        return self._loads_and_supports(z, out)

    def _loads_and_supports(self, z, out):
        """Add the loads' impulses (-h f_ext on the r rows, -h F_i of a tip torque on node N's director rows); replace
        the held unknowns' rows by their increments z."""
        if np.any(self.fext):
            o = out.reshape(out.shape[:-1] + (self.N + 1, self.nv))
            o[..., :3] -= self.h * self.fext
        if self.has_torque:
            o = out.reshape(out.shape[:-1] + (self.N + 1, self.nv))
            o[..., -1, 3:12] -= self.h * self._torque_forces(z).reshape(z.shape[:-1] + (9,))
        if np.any(self.fixed):
            out[..., self.fixed] = z[..., self.fixed]
        return out

    def _torque_forces(self, z):
        """The tip torque's director forces at node N (.., 3, 3) at the mean directors of z's step."""
        dDN = z.reshape(z.shape[:-1] + (self.N + 1, self.nv))[..., -1, 3:12].reshape(z.shape[:-1] + (3, 3))
        return tip_torque_forces(self.D[-1] + 0.5 * dDN, self.torque)

    def _kernel(self, z, out):
        _k_residual(self.r, self.D, self.v, self.V, self.m, self.E, z, self.h, self.ds, self.Jd, self.Kd, self.nv, out)
        self._loads_and_supports(z, out)

    def residual_compiled(self, z):
        """:meth:`residual` of one real z by the compiled kernel ``_k_residual`` (tested equal)."""
        out = np.empty((1, z.size))
        self._kernel(np.ascontiguousarray(z, dtype=np.float64)[None, :], out)
        return out[0]

    def jacobian(self, z, body=False):
        """Sparse Jacobian by complex step (exact to round-off), 3-node colouring: 3 nv batched residuals.  With
        ``body``, T^T J T (Newton's matrix in the level's body frames, :meth:`_body_frames`): the perturbations are
        taken along T's columns and the residuals' rows turned by T^T (T is node-block diagonal, so the colouring
        still separates the columns), instead of two sparse products."""
        n = (self.N + 1) * self.nv
        if self._plan is None:
            node = np.arange(n) // self.nv
            comp = np.arange(n) % self.nv
            rows, cols = [], []
            for j in range(self.N + 1):
                for k in range(max(0, j - 1), min(self.N, j + 1) + 1):
                    rr, cc = np.meshgrid(np.arange(j * self.nv, (j + 1) * self.nv), np.arange(k * self.nv, (k + 1) * self.nv), indexing="ij")
                    rows.append(rr.ravel())
                    cols.append(cc.ravel())
            rows, cols = np.concatenate(rows), np.concatenate(cols)
            self._plan = (node, comp, rows, cols)
        node, comp, rows, cols = self._plan
        eps = 1e-30
        P = np.zeros((3 * self.nv, n), dtype=complex)
        for col in range(3):
            for c in range(self.nv):
                P[col * self.nv + c, (node % 3 == col) & (comp == c)] = 1j * eps
        if body:
            for b in range(P.shape[0]):
                P[b] = 1j * eps * self._rotate(P[b].imag / eps)
        zc = z[None, :] + P
        if self.compiled:
            Rc = np.empty_like(zc)
            self._kernel(zc, Rc)
            Rc = Rc.imag / eps
        else:
            Rc = self.residual(zc).imag / eps  # (3 nv, n)
        self.stats["residuals"] += P.shape[0]
        if body:
            Rc = np.array([self._rotate(row, transpose=True) for row in Rc])
        # entry (row, col) comes from the batch of col's colour and component
        b = (node[cols] % 3) * self.nv + comp[cols]
        vals = Rc[b, rows]
        return sp.csc_matrix((vals, (rows, cols)), shape=(n, n))

    def _pack(self, r, D, lam, mu=None):
        parts = [r, D.reshape(-1, 9), lam] + ([self.mu if mu is None else mu] if self.constrained else [])
        return np.concatenate(parts, 1).ravel()

    def body_angular_velocity(self):
        return body_angular_velocity(self.D, self.V)

    def _predict_rigid(self):
        from ..lattice.lie import cay

        return self._pack(self.h * self.v, self.D @ cay(self.h * self.body_angular_velocity()) - self.D, self.lam)

    def _predict_rest(self):
        return self._pack(np.zeros_like(self.r), np.zeros_like(self.D), self.lam)

    def _predict(self):
        """The last step repeated (increments r_n - r_{n-1} and D_n D_{n-1}^T D_n - D_n); the first step a rigid motion
        at the initial velocities.  The level velocities are a poor guess at unresolved steps (the stiff modes flip sign
        every step): repeating the last increment halves the predictor error on the hard cases."""
        if self._prev is None:
            return self._predict_rigid()
        dr_, D_ = self._prev
        return self._pack(dr_, self.D @ (_T(D_) @ self.D) - self.D, self.lam)

    def _body_frames(self):
        """T = blockdiag(D_n, D_n (x) I_3, I_6) per node: the unknowns' updates in the level's body frames
        (dr = D_n db, dD = D_n dB).  Newton solves T^T J T du = -T^T R: that matrix does not rotate with the rod
        (J(Q z) = Q J(z) Q^T for a rigid turn Q; a dead tip torque, fixed in space, breaks this by O(h |T|)), so a
        factorisation is reused across steps of a spinning rod as the midpoint's body-frame unknowns are
        (docs/theory.md §9)."""
        D = self.D
        blk = np.zeros((self.N + 1, self.nv, self.nv))
        blk[:, :3, :3] = D
        for a in range(3):
            for b in range(3):
                blk[:, 3 + 3 * a: 6 + 3 * a, 3 + 3 * b: 6 + 3 * b] = D[:, a, b, None, None] * np.eye(3)
        blk[:, 12:, 12:] = np.eye(self.nv - 12)
        n = self.N + 1
        return sp.bsr_matrix((blk, np.arange(n), np.arange(n + 1)), shape=(n * self.nv, n * self.nv)).tocsr()

    def _rotate(self, x, transpose=False):
        """T x (or T^T x) for the block-diagonal T of :meth:`_body_frames`, by node blocks instead of a sparse product."""
        out = np.empty_like(x)
        _k_rotate(self.D, x, self.nv, transpose, out)
        return out

    def _factor(self, z):
        """SuperLU of the body-frame Jacobian at z (a singular matrix: SolverError)."""
        try:
            lu = spla.splu(self.jacobian(z, body=True))
        except RuntimeError as exc:  # SuperLU: "Factor is exactly singular"
            raise SolverError(f"step {self.n + 1}: singular Newton matrix ({exc})") from None
        self.stats["jacobians"] += 1
        return lu

    def _solve(self, z, chord):
        """:func:`chord_newton` with the compiled residual and the body-frame factorisation."""
        return chord_newton(self, z, chord, self.residual_compiled if self.compiled else self.residual, self._factor,
                            lambda R: self._rotate(self._lu.solve(self._rotate(-R, transpose=True))),
                            lambda dz: float(np.max(np.abs(dz[self._qmask]) / self._update_scale)))

    def step(self):
        """Advance one step; returns the number of Newton iterations (:func:`em_step`: chord Newton from the predictor,
        the last increment; on failure full Newton from a rigid motion at the level's velocities, from the last
        increment and from rest; then :func:`halved_step`).  The rigid motion first: where the chord attempt fails
        (the stiff modes unresolved), full Newton converges from it more often (the tumbling rod at h = 10 ms:
        7 Jacobians and 12 ms per step against 20 and 38 from the last increment first)."""
        return em_step(self, (self._predict_rigid, self._predict, self._predict_rest))

    def _advance(self, z, it):
        """Take Newton's solution z as the step: the held unknowns, the rigid polish, the new level and velocities."""
        h = self.h
        z[self.fixed] = 0.0  # held unknowns exactly at the level (Newton leaves them within round-off of it)
        if self.free:
            z = self._polish_rigid(z)
        dr, dD, lam = self._unpack(z)
        if self.constrained:
            self.mu = z.reshape(self.N + 1, self.nv)[:, NV:].copy()
        if self.has_torque:
            self.work += float(np.sum(self._torque_forces(z) * dD[-1]))
        # the velocities from the increments themselves, not from differences of rounded positions: the momenta then
        # change by the residual's floor only (docs/theory.md §12a, "Momenta to round-off")
        self.v = 2.0 * dr / h - self.v
        self.V = 2.0 * dD / h - self.V
        self._prev = (dr.copy(), self.D)
        self.r, self.D, self.lam = self.r + dr, self.D + dD, lam.copy()
        if self.floating_origin:
            shift = origin_shift(self.r[0])
            self.r, self.origin = self.r - shift, self.origin + shift
        # d_1 has no inertia: its level velocity is set to the rigid one of the frame (it enters nothing)
        W = self.body_angular_velocity()
        self.V[:, :, 0] = np.einsum("nij,nj->ni", self.D, np.cross(W, CHI))
        self.n += 1
        self.stats["iterations"] += it

    def _guess_over(self, before):
        """The step's unknowns from the level in ``before`` (:meth:`state_data`) to the current one: increments and
        the current multipliers (halved_step's start for Newton at h)."""
        r0 = np.asarray(before["em_r"], dtype=float).reshape(self.r.shape)
        D0 = np.asarray(before["em_D"], dtype=float).reshape(self.D.shape)
        moved = self.origin - before["em_origin"]  # the floating origin's moves since
        return self._pack(self.r + moved - r0, self.D - D0, self.lam)

    def _prev_of(self, z):
        """The predictor's data (the last increment and the level it started from) for the step's unknowns z."""
        dr, dD, _ = self._unpack(z)
        return dr.copy(), self.D - dD

    def _momentum_residuals(self, z):
        """The step's linear and angular momentum balances (sum R_r, sum rbar x R_r + dbar_i x R_d_i) from their closed
        forms: the internal and constraint forces' sums vanish identically (docs/theory.md §12a), so only the inertial
        and load terms remain.  Evaluated this way they carry the round-off of the momenta (eps m|v|), not that of the
        stiff forces (eps h|F|) that the full residual's sums carry."""
        h = self.h
        dr, dD, _ = self._unpack(z)
        rb = self.r + 0.5 * dr
        Db = self.D + 0.5 * dD
        fr = (2.0 / h) * self.m[:, None] * (dr - h * self.v) - h * self.fext
        fD = (2.0 / h) * self.E[:, None, :] * (dD - h * self.V)
        if self.has_torque:
            fD[-1] -= h * self._torque_forces(z)
        P = fr.sum(0)
        J = np.cross(rb, fr).sum(0) + np.cross(np.swapaxes(Db, 1, 2), np.swapaxes(fD, 1, 2)).sum((0, 1))
        return P, J, rb, Db

    def _polish_rigid(self, z):
        """One (quasi-)Newton correction of the solution in the six rigid directions (dr += a + w x rbar, dd_i += w x dbar_i)
        that zeroes the momentum balances of :meth:`_momentum_residuals`.  Newton's last iterate leaves the full
        residual at its floor eps h|F| (the stiff forces' rounding); in the rigid directions, where the forces' sums
        are known to vanish, the balances can be met to eps m|v|: without this the momenta random-walk by ~1e-12 over
        10^5 steps of the hard cases, with it by ~1e-14 (docs/theory.md §12a, "Momenta to round-off").  The
        correction is of the residual floor's size, so every other row stays at its floor."""
        P, J, rb, Db = self._momentum_residuals(z)
        a, w = rigid_correction(self.h, P, J, self.m, rb, self.E, Db)
        d = np.swapaxes(Db, 1, 2)
        z = z.copy()
        zz = z.reshape(self.N + 1, self.nv)
        zz[:, :3] += a + np.cross(w, rb)
        zz[:, 3:12] += np.swapaxes(np.cross(w, d), 1, 2).reshape(-1, 9)
        return z

    def step_state(self, st, model):
        """One step, returned as the stepper's :class:`varint.schemes.state.State` (q: frames and positions; p: the node
        momenta m v and the body angular momenta Pi = D^T sum_i d_i x E_i d_i').  A state whose level n differs from
        the step's own is taken as a resumed run and restored from its data (state_data); a different state at the
        same level is not detected (the stepper only ever passes back what this returned)."""
        from ..terms.rod import pack_level
        from .state import State

        if st.n != self.n:  # a resumed run: the step's own state travels in the checkpoint's data (state_data)
            if not st.data or "em_r" not in st.data:
                raise SolverError("time.scheme: 'energy-momentum' cannot restart from this checkpoint (it lacks the "
                                  "step's director velocities: written by an older varint)")
            self.restore(st.data, st.n)
        self.step()
        q, p = st.q.copy(), st.p.copy()
        q[model.rod_q] = pack_level(self.D, self.r, self.origin)
        Pi = np.einsum("nji,nj->ni", self.D, np.cross(np.swapaxes(self.D, 1, 2),
                                                      np.swapaxes(self.E[:, None, :] * self.V, 1, 2)).sum(1))
        p[model.rod_p] = np.concatenate([(self.m[:, None] * self.v).ravel(), Pi.ravel()])
        data = dict(st.data or {})
        data.update(self.state_data())
        return State(self.n, self.n * self.h, q, p, st.lam, st.v, st.q.copy(), data)

    #: the step's own state, beyond (q, p): the director velocities V (the level momenta keep only their skew part,
    #: Pi), the multipliers (Newton's start) and the last increment (the predictor)
    _STATE = ("r", "D", "v", "V", "lam", "mu")

    def state_data(self):
        """The step's state as flat arrays for a checkpoint (``State.data``; varint/run/io.py writes them)."""
        data = {f"em_{k}": np.asarray(getattr(self, k), dtype=float).ravel() for k in self._STATE}
        data["em_origin"] = self.origin.copy()
        data["em_work"] = np.array([self.work])
        if self._prev is not None:
            data["em_prev_dr"], data["em_prev_D"] = self._prev[0].ravel(), self._prev[1].ravel()
        return data

    def restore(self, data, n):
        """Continue from :meth:`state_data` at level n (a resumed run).  The kept factorisation is dropped: the
        resumed run differs from the uninterrupted one by Newton's round-off only."""
        for k in self._STATE:
            cur = getattr(self, k)
            setattr(self, k, np.array(data[f"em_{k}"], dtype=float).reshape(cur.shape))
        # a checkpoint written before the floating origin: its positions are absolute
        self.origin = np.array(data.get("em_origin", np.zeros(3)), dtype=float).reshape(3)
        self.work = float(np.asarray(data.get("em_work", [0.0])).ravel()[0])
        self._prev = None
        if "em_prev_dr" in data:
            self._prev = (np.array(data["em_prev_dr"], dtype=float).reshape(self.r.shape),
                          np.array(data["em_prev_D"], dtype=float).reshape(self.D.shape))
        self.n = int(n)
        self._lu = None

    def monitors(self):
        """The conserved energy (kinetic in the director velocities) and momenta, for the stepper's monitors."""
        kin = 0.5 * np.sum(self.m * np.sum(self.v ** 2, 1)) + 0.5 * np.sum(self.E[:, None, :] * self.V ** 2)
        E = self.energy()
        out = {"energy": E, "kinetic_energy": float(kin), "linear_momentum": self.linear_momentum(),
               "angular_momentum": self.angular_momentum(), "frame_orthogonality": self.orthonormality()}
        if self.has_torque:
            out["external_work"] = self.work  # the tip torque's, since t = 0: E - external_work is conserved
        return out

    # -- monitors ------------------------------------------------------------------------------------

    def energy(self):
        """The conserved total energy: 1/2 m |v|^2 + 1/2 E_i |d_i'|^2 + U, the loads' work on r + o in two parts."""
        kin = 0.5 * np.sum(self.m * np.sum(self.v ** 2, 1)) + 0.5 * np.sum(self.E[:, None, :] * self.V ** 2)
        return float(kin + potential(self.r, self.D, self.ds, self.Jd, self.Kd) - np.sum(self.fext * self.r)
                     - float(self.fext.sum(0) @ self.origin))

    def linear_momentum(self):
        return (self.m[:, None] * self.v).sum(0)

    def angular_momentum(self):
        """About the fixed origin: the floating origin's o x P plus the moments about o."""
        return (np.cross(self.origin, self.linear_momentum()) + np.cross(self.r, self.m[:, None] * self.v).sum(0)
                + np.cross(np.swapaxes(self.D, 1, 2), np.swapaxes(self.E[:, None, :] * self.V, 1, 2)).sum((0, 1)))

    def orthonormality(self):
        return float(np.max(np.abs(_T(self.D) @ self.D - np.eye(3))))


# ---------------------------------------------------------------------------------------------------------------------
# compiled residual (the same equations as RodEMStep.residual, which stays the readable reference; tested equal).
# One kernel serves real arguments (chord iterations) and complex ones (the complex-step Jacobian's batch).

from numba import njit  # noqa: E402


@njit(cache=True, error_model="numpy")
def _k_residual(r0, D0, v0, V0, m, E, z, h, ds, Jd, Kd, nv, out):
    """nv = 18 per node, or 21 with rod.constraint (mu_e at entries 18-20 of element e's first node)."""
    B, n = z.shape
    N1 = r0.shape[0]
    # scratch, allocated once per call (not per element: the allocations were a third of the kernel's time)
    r1 = np.empty((N1, 3), dtype=z.dtype)
    D1 = np.empty((N1, 3, 3), dtype=z.dtype)
    Fr = np.empty((N1, 3), dtype=z.dtype)
    FD = np.empty((N1, 3, 3), dtype=z.dtype)
    Dbar = np.empty((N1, 3, 3), dtype=z.dtype)
    G1 = np.empty((N1 - 1, 3), dtype=z.dtype)
    stress = np.empty((N1 - 1, 3), dtype=z.dtype)
    W = np.empty((7, 3), dtype=z.dtype)
    M = np.empty((2, 3, 3), dtype=z.dtype)
    # the level's strains (real), the same for every row
    Om0, G0, pa, pb, a0 = (np.empty((N1 - 1, 3)), np.empty((N1 - 1, 3)), np.empty((N1 - 1, 3)), np.empty((N1 - 1, 3)),
                           np.empty((N1 - 1, 3)))
    c0 = np.empty(N1 - 1)
    k_level_strains(r0, D0, ds, Om0, G0, pa, pb, a0, c0, np.empty((3, 3)), np.empty(3), np.empty(3))
    for b in range(B):
        zb = z[b]
        ob = out[b]
        # the level-1 configuration from the increments (the unknowns; see RodEMStep.residual)
        for j in range(N1):
            for k in range(3):
                r1[j, k] = r0[j, k] + zb[nv * j + k]
                for i in range(3):
                    D1[j, k, i] = D0[j, k, i] + zb[nv * j + 3 + 3 * k + i]
        for j in range(N1):
            o = nv * j
            for k in range(18, nv):
                ob[o + k] = 0.0  # the constraint rows are the elements' (below); node N's is no element's
            for k in range(3):
                ob[o + k] = (2.0 / h) * m[j] * (zb[o + k] - h * v0[j, k])
            l0, l1, l2, l3, l4, l5 = zb[o + 12], zb[o + 13], zb[o + 14], zb[o + 15], zb[o + 16], zb[o + 17]
            for i in range(3):
                # constraint force (Db S)_ik, S = [[2l0, l3, l4], [l3, 2l1, l5], [l4, l5, 2l2]]
                d0 = 0.5 * (D0[j, i, 0] + D1[j, i, 0])
                d1 = 0.5 * (D0[j, i, 1] + D1[j, i, 1])
                d2 = 0.5 * (D0[j, i, 2] + D1[j, i, 2])
                f0 = d0 * 2.0 * l0 + d1 * l3 + d2 * l4
                f1 = d0 * l3 + d1 * 2.0 * l1 + d2 * l5
                f2 = d0 * l4 + d1 * l5 + d2 * 2.0 * l2
                ob[o + 3 + 3 * i] = (2.0 / h) * E[j, 0] * (zb[o + 3 + 3 * i] - h * V0[j, i, 0]) + h * f0
                ob[o + 4 + 3 * i] = (2.0 / h) * E[j, 1] * (zb[o + 4 + 3 * i] - h * V0[j, i, 1]) + h * f1
                ob[o + 5 + 3 * i] = (2.0 / h) * E[j, 2] * (zb[o + 5 + 3 * i] - h * V0[j, i, 2]) + h * f2
            # constraints D1^T D1 - I: (00, 11, 22, 01, 02, 12)
            for p in range(6):
                if p < 3:
                    a1, a2 = p, p
                elif p == 3:
                    a1, a2 = 0, 1
                elif p == 4:
                    a1, a2 = 0, 2
                else:
                    a1, a2 = 1, 2
                s = D1[j, 0, a1] * D1[j, 0, a2] + D1[j, 1, a1] * D1[j, 1, a2] + D1[j, 2, a1] * D1[j, 2, a2]
                ob[o + 12 + p] = s - (1.0 if a1 == a2 else 0.0)
        # the rod's discrete gradient (its stress: rod.constraint's mu_e; its rows Gamma_e(q_1) - chi)
        for e in range(N1 - 1):
            for i in range(3):
                stress[e, i] = zb[nv * e + 18 + i] if nv > 18 else 0.0
        k_dg_row(r0, D0, Om0, G0, a0, c0, r1, D1, ds, Jd, Kd, stress, Fr, FD, G1, Dbar, W, M)
        for j in range(N1):
            o = nv * j
            for k in range(3):
                ob[o + k] += h * Fr[j, k]
                for i in range(3):
                    ob[o + 3 + 3 * k + i] += h * FD[j, k, i]
            if nv > 18 and j < N1 - 1:
                for i in range(3):
                    ob[o + 18 + i] = G1[j, i] - CHI[i]


@njit(cache=True, inline="always")
def k_dg_row(r0, D0, Om0, G0, a0, c0, r1, D1, ds, Jd, Kd, stress, Fr, FD, G1, Dbar, W, M):
    """The rod's discrete gradient grad_d U(q_0, q_1) (docs/theory.md §12a) of U = sum_e ds (1/2 Omega.J Omega +
    1/2 (Gamma - chi).K (Gamma - chi)) between a level (r0 (N+1, 3), D0 (N+1, 3, 3), with its strains Om0, G0, a0
    (N, 3), c0 (N,) from varint.terms.rod.k_strains_row) and a configuration (r1, D1), with ``stress`` (N, 3) added to
    the mean-strain stress n: Fr (N+1, 3) and FD (N+1, 3, 3) receive the forces on the positions and the directors,
    G1 (N, 3) Gamma at (r1, D1).  The strains are the rod's (varint.terms.rod.k_gamma, k_turn): Gamma and R = D_a^T D_b
    are bilinear, so their midpoint derivatives map q_1 - q_0 exactly onto the strain changes, and Omega = 2 a / (c ds)
    uses a_1/c_1 - a_0/c_0 = (c_bar da - a_bar dc)/(c_0 c_1).  Scratch of the scalar type of (r1, D1): Dbar
    (N+1, 3, 3), W (7, 3), M (2, 3, 3).  :func:`rod_discrete_gradient` on a batch, and the rod's residual."""
    N = r1.shape[0] - 1
    d1, a1, om1, n, m, drb, al = W[0], W[1], W[2], W[3], W[4], W[5], W[6]
    T, Phi = M[0], M[1]
    for j in range(N + 1):
        for p in range(3):
            Fr[j, p] = 0.0
            for q in range(3):
                FD[j, p, q] = 0.0
                Dbar[j, p, q] = 0.5 * (D0[j, p, q] + D1[j, p, q])
    for e in range(N):
        for i in range(3):
            d1[i] = r1[e + 1, i] - r1[e, i]
        k_gamma(D1[e], D1[e + 1], d1, ds, G1[e])
        c1, a1[0], a1[1], a1[2] = k_turn(D1[e], D1[e + 1], T, om1)
        icc = 1.0 / (c0[e] * c1)
        beta = 0.0 * icc
        for i in range(3):
            n[i] = Kd[i] * (0.5 * (G0[e, i] + G1[e, i]) - CHI[i]) + stress[e, i]  # the stress at the mean strain
            m[i] = Jd[i] * 0.5 * (Om0[e, i] + om1[i] / ds)  # the couple at the mean curvature
            drb[i] = 0.5 * (r0[e + 1, i] + r1[e + 1, i]) - 0.5 * (r0[e, i] + r1[e, i])
            # bending-torsion: ds m . dOmega = alpha . da + beta dc, with R = D_a^T D_b bilinear
            al[i] = (c0[e] + c1) * m[i] * icc
            beta += -(a0[e, i] + a1[i]) * m[i] * icc
        for i in range(3):
            # stretch-shear: ds n . dGamma, dGamma = 1/2 (Db_a + Db_b)^T (dr_b - dr_a)/ds + 1/2 (dD_a + dD_b)^T drb/ds
            f = 0.0 * icc
            for j in range(3):
                f += 0.5 * (Dbar[e, i, j] + Dbar[e + 1, i, j]) * n[j]
            Fr[e + 1, i] += f
            Fr[e, i] -= f
            for j in range(3):
                g = 0.5 * drb[i] * n[j]
                FD[e, i, j] += g
                FD[e + 1, i, j] += g
        k_hat(al, 1.0, Phi)  # Phi = hat(alpha) + beta I: the derivative of alpha . a + beta c in R
        for i in range(3):
            Phi[i, i] = beta
        for i in range(3):
            for j in range(3):
                FD[e, i, j] += Dbar[e + 1, i, 0] * Phi[j, 0] + Dbar[e + 1, i, 1] * Phi[j, 1] + Dbar[e + 1, i, 2] * Phi[j, 2]
                FD[e + 1, i, j] += Dbar[e, i, 0] * Phi[0, j] + Dbar[e, i, 1] * Phi[1, j] + Dbar[e, i, 2] * Phi[2, j]


#: the period a closed rod's strains do not read (its own array: the strains' scratch ``d`` must not alias it)
_NO_PERIOD = np.zeros(3)


@njit(cache=True, inline="always")
def k_level_strains(r0, D0, ds, Om0, G0, pa, pb, a0, c0, T, d, om):
    """The level's strains that :func:`k_dg_row` reads (varint.terms.rod.k_strains_row of a closed rod)."""
    k_strains_row(D0, r0, ds, False, _NO_PERIOD, Om0, G0, pa, pb, a0, c0, T, d, om)


@njit(cache=True)
def rod_discrete_gradient(r0, D0, r1, D1, ds, Jd, Kd, stress, Fr, FD):
    """grad_d U of the rod (:func:`k_dg_row`) between the level (r0 (B0, N+1, 3), D0 (B0, N+1, 3, 3): one row read by
    every row of the batch, or one per row) and each row b of (r1 (B, N+1, 3), D1 (B, N+1, 3, 3)), with stress (B, N, 3)
    added to the mean-strain stress n: Fr (B, N+1, 3), FD (B, N+1, 3, 3).  :func:`discrete_gradient` of NumPy arrays,
    and the coupled tube's energy-momentum residual (varint.schemes.em_tube: the fluid's stress, rod.constraint's mu)."""
    N = r1.shape[1] - 1
    dt = Fr.dtype
    l0 = D0.dtype
    Om0, G0, pa, pb, a0 = (np.empty((N, 3), l0), np.empty((N, 3), l0), np.empty((N, 3), l0), np.empty((N, 3), l0),
                           np.empty((N, 3), l0))
    c0, T0, d0, om0 = np.empty(N, l0), np.empty((3, 3), l0), np.empty(3, l0), np.empty(3, l0)
    G1 = np.empty((N, 3), dt)
    Dbar = np.empty((N + 1, 3, 3), dt)
    W = np.empty((7, 3), dt)
    M = np.empty((2, 3, 3), dt)
    for b in range(r1.shape[0]):
        b0 = b if r0.shape[0] > 1 else 0
        if b == b0:  # the level's strains: once, or per row
            k_level_strains(r0[b0], D0[b0], ds, Om0, G0, pa, pb, a0, c0, T0, d0, om0)
        k_dg_row(r0[b0], D0[b0], Om0, G0, a0, c0, r1[b], D1[b], ds, Jd, Kd, stress[b], Fr[b], FD[b], G1, Dbar, W, M)


@njit(cache=True)
def _k_rotate(D, x, nv, transpose, out):
    """out = T x or T^T x, T = blockdiag(D_j, D_j (x) I_3, I) per node (RodEMStep._body_frames)."""
    for j in range(D.shape[0]):
        o = nv * j
        for k in range(nv):
            out[o + k] = x[o + k]
        for a in range(3):
            s = 0.0
            for b in range(3):
                s += (D[j, b, a] if transpose else D[j, a, b]) * x[o + b]
            out[o + a] = s
            for c in range(3):
                s = 0.0
                for b in range(3):
                    s += (D[j, b, a] if transpose else D[j, a, b]) * x[o + 3 + 3 * b + c]
                out[o + 3 + 3 * a + c] = s
