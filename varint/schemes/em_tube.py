"""The energy-momentum step for the coupled tube: rod + wall + fluid (``time.scheme = "energy-momentum"`` with
``[fluid]``; docs/theory.md §12b).

It extends the rod's energy-momentum step (:mod:`varint.schemes.em_rod`, theory §12a: directors as configuration, a
discrete gradient of the rod's potential, orthonormality held by multipliers) to the coupled tube of theory §10 along
the route written at the end of §12a:

* each interior fluid label k carries its *spatial* position X_k as an unknown with the constant kinetic metric
  1/2 mbar_k |X_k'|^2, and the holonomic constraint c_k = D_e^T (X_k - sum_i N_i(s_k) r_i) = 0 (Catmull-Rom weights of
  §10.2, D_e the directors of the node nearest the label, fixed for the step) held at the levels by multipliers nu_k.
  Its product-rule discrete derivative (every factor a rigid invariant, D_e^T X_k, D_e^T r_i, N_i(s_k)) is exact and
  annihilates the rigid motions at the step's arithmetic midpoint;
* the end labels sit on the end nodes (X_0 = r_0, X_M = r_N exactly): their masses join the end nodes';
* the fluid's energy sum_k psi_k(V_k) (or the liquid's constraint V_k = V0_k) and p_ext sum_k V_k are taken at the
  *levels*, with the parcel volumes of §10.3 (R and the nodal stretch gamma linear on each element) written as
  sums of P * S: P = R_i R_j gamma_l a product of nodal values, whose average-vector-field derivative is exact in
  closed form, and S a difference of the moment polynomials M_q at the clipped label coordinates, whose divided
  difference is exact and computed without cancellation; psi by a divided difference (Gauss-Legendre of -p for
  small volume changes); gamma through Delta|Gamma_e| = (Gamma^0 + Gamma^1) . Delta Gamma_e / (|Gamma^0| + |Gamma^1|)
  with Gamma bilinear (its midpoint derivative exact and rigid-free);
* the wall's kinetic energy 1/2 a w_j R_j'^2 (constant metric) and its energy (WallLinear quadratic: midpoint
  gradient exact; WallTubeLaw through A = pi R^2 with exact divided differences).

So U(q_1) - U(q_0) = grad_d U(q_0, q_1) . (q_1 - q_0) for any two configurations, the constraint forces do no work
between two levels that hold the constraints, and every force annihilates the rigid motions at q_bar: the total
energy is conserved to the solver's residual and P, J to its floor (tested in tests/test_tube_em.py).

Scope in this version: closed fluid ends; free, pinned or clamped rod ends; rigid or dynamic wall (linear law or
tube law); ideal gas, barotropic liquid or incompressible liquid; gravity, a dead tip force, p_ext; rod.constraint.
Not covered (the scene check refuses them in one line naming time.scheme): open or periodic ends, a quasistatic
wall, shock capturing and other non-conservative forces (a dead tip torque is covered: its work is summed), the
paper's measure.

Newton (as :class:`varint.schemes.em_rod.RodEMStep`): chord iterations on a kept SuperLU factorisation of the Jacobian in the
level's body frames (T^T J T: r, D and the labels' X turned by the directors, so the matrix survives a rigid turn;
a dead tip torque breaks this by O(h |T|), and the chord still converges),
refreshed when the contraction is slower than 1/2; the Jacobian by complex step with a colouring of its columns
(the pattern by location from the stencils, :meth:`TubeEMStep._cliques`; ~110 batched residuals at 20 or 40
elements with a liquid), each one checked against a random directional derivative in the same batch; a rigid
correction of the solution zeroes the momentum balances.  The residual's three heavy parts (the fluid's pairs, the
labels' constraint, the rod's discrete gradient) run as compiled loops (varint/schemes/em_tube_kernels.py; the rod's
discrete gradient is the rod's own, varint.schemes.em_rod.rod_discrete_gradient) on real iterates and on the Jacobian's
complex batches; the numpy code beside the first two is the reference (``compiled = False``), tested equal to
round-off.  A residual is then ~0.6-0.8 ms at 12-20 elements, and the 15-20 chord iterations per step and
a Jacobian every 1-4 steps share the cost (docs/performance.md, "The coupled tube's energy-momentum step").
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from . import em_rod
from . import em_tube_kernels as kernels
from ..errors import SolverError
from ..lattice.centreline import CR, GHOST, MQ, nodal_stretch
from ..terms.coupled_shock_capturing import CoupledShockCapturing
from ..terms.rod import origin_shift
from ..terms.shock_capturing import heated_entropy, viscous_pressure_q
from .em_rod import (CHI, _PAIRS, _T, _hat, body_angular_velocity, chord_newton, director_masses, discrete_gradient, em_step,
                     potential, rigid_correction, rod_discrete_gradient, strains, tip_torque_forces)

_GL_X, _GL_W = np.polynomial.legendre.leggauss(8)
_GL_X, _GL_W = 0.5 * (_GL_X + 1.0), 0.5 * _GL_W  # on [0, 1]



# -- exact, cancellation-free divided differences ------------------------------------------------------------------


def _pows_dd(a, b, n):
    """(b^p - a^p)/(b - a) = sum_i a^i b^(p-1-i) for p = 1..n on a new last axis, exact for a = b too (by
    dd_p = a dd_(p-1) + b^(p-1))."""
    a, b = np.broadcast_arrays(a, b)
    dd = [np.ones(a.shape, dtype=np.result_type(a, b, float))]
    bp = b
    for _ in range(1, n):
        dd.append(a * dd[-1] + bp)
        bp = bp * b
    return np.stack(dd, -1)


def _pows(t, lo, hi):
    """t^p for p = lo..hi on a new last axis."""
    out = [np.ones_like(t) if lo == 0 else t ** lo]
    for _ in range(lo, hi):
        out.append(out[-1] * t)
    return np.stack(out, -1)


def _cr(t):
    """The four Catmull-Rom weights (nodes e-1..e+2) at local coordinates t (.., 4)."""
    return np.einsum("...p,ip->...i", _pows(t, 0, 3), CR)


def _cr_dd(a, b):
    """Their divided differences between a and b (.., 4), without cancellation."""
    return np.einsum("...p,ip->...i", _pows_dd(a, b, 3), CR[:, 1:])


def _clip01(t):
    """t clipped to [0, 1] by its real part (complex steps pass through inside)."""
    re = np.real(t)
    return np.where(re < 0.0, 0.0, np.where(re > 1.0, 1.0, t))


def _moment_dd(t0, t1, last):
    """(M_q(clip t1) - M_q(clip t0))/(t1 - t0) for q = 0..3 (last axis), exact and cancellation-free: the polynomial
    divided difference between the clipped ends times the fraction of [t0, t1] inside [0, 1].  Where the two levels'
    coordinates are equal (real parts; a complex step only adds an imaginary part) it is the derivative on the element
    that owns the point: [0, 1) as ``_element_of``'s floor, [0, 1] on the ``last`` element — a label exactly on a node
    must not count on both of its elements."""
    c0, c1 = _clip01(t0), _clip01(t1)
    dt = t1 - t0
    same = np.real(dt) == 0
    re = np.real(t0)
    owns = (re >= 0) & ((re < 1) | (last & (re <= 1)))
    frac = np.where(same, np.where(owns, 1.0, 0.0), (c1 - c0) / np.where(same, 1.0, dt))
    dd = np.einsum("...p,qp->...q", _pows_dd(c0, c1, 4), MQ)
    return dd * frac[..., None]


def _clip_owned(t, last):
    """t clipped to [0, 1] by its real part, where only the element that owns the point passes a complex step through
    at its end: [0, 1) as ``_element_of``'s floor, [0, 1] on the ``last`` element.  A label exactly on a node sits at
    t = 1 on one element and t = 0 on the next; passing the step through on both would count its derivative twice."""
    re = np.real(t)
    return np.where(re < 0.0, 0.0, np.where((re > 1.0) | ((re == 1.0) & ~np.asarray(last)), 1.0, t))


def _moments(t, last):
    """M_q(clip t), q = 0..3 (last axis); ``last``: the pair is on the last element (:func:`_clip_owned`)."""
    return np.einsum("...p,qp->...q", _pows(_clip_owned(t, last), 1, 4), MQ)


def _over(s, ds):
    """s/ds with its real part rounded as the real division's: numpy's complex division rounds the real part
    differently (5.0 against 5.000000000000001 for 0.8333333333333334/0.16666666666666666), which would put a
    complex-stepped label on a node in another branch than the real iterate (and than the compiled loops)."""
    if np.iscomplexobj(s):
        return np.real(s) / ds + 1j * (np.imag(s) / ds)
    return s / ds


def _batch_rows(x, batch, tail, dtype):
    """x broadcast to the batch's shape ``batch + tail`` as contiguous rows (-1,) + tail of ``dtype`` (the compiled
    loops' layout; no copy where x already is one)."""
    return np.ascontiguousarray(np.broadcast_to(x, batch + tail), dtype=dtype).reshape((-1,) + tail)


def scalar_dd(f, df, x0, x1):
    """(f(x1) - f(x0))/(x1 - x0), exact to round-off without cancellation: Gauss-Legendre (8 points) of f' where the
    relative change is below 5 % (error ~ (dx/x)^16), the difference quotient itself above."""
    dx = x1 - x0
    small = np.abs(np.real(dx)) < 0.05 * np.abs(np.real(x0))
    quad = sum(w * df(x0 + xg * dx) for xg, w in zip(_GL_X, _GL_W))
    direct = (f(x1) - f(x0)) / np.where(small, 1.0, dx)
    return np.where(small, quad, direct)


_Q = np.add.outer(np.add.outer(np.arange(2), np.arange(2)), np.arange(2))  # q = i + j + l


def _ends(x, pe):
    """x at the two nodes of each pair's element (.., npairs, 2)."""
    return np.stack([x[..., pe], x[..., pe + 1]], -1)


def _triple(Rp, Gp):
    """P_(ijl) = R_i R_j gamma_l (.., npairs, 2, 2, 2) from the pairs' end values."""
    return Rp[..., :, None, None] * Rp[..., None, :, None] * Gp[..., None, None, :]


def _scatter(x, idx, n):
    """out[..., i] = sum of x[..., p] over p with idx[p] = i (the pairs summed into parcels, labels or nodes), by
    bincount on the real and imaginary parts (no BLAS call: a threaded BLAS stalls on small products when the
    machine is loaded)."""
    b = x.shape[:-1]
    B = int(np.prod(b, dtype=int))
    flat = (np.arange(B)[:, None] * n + idx[None, :]).ravel()
    x2 = x.reshape(B, -1)
    out = np.bincount(flat, x2.real.ravel(), B * n)
    if np.iscomplexobj(x):
        out = out + 1j * np.bincount(flat, x2.imag.ravel(), B * n)
    return out.reshape(b + (n,))


def _avf2(x0, x1, y0, y1):
    """int_0^1 x(tau) y(tau) dtau for x, y linear between their two levels (the AVF weight of a product)."""
    return (x0 * y0 + x1 * y1) / 3.0 + (x0 * y1 + x1 * y0) / 6.0


# -- Catmull-Rom weights of the labels (complex-safe) --------------------------------------------------------------


def _element_of(s, ds, n_el):
    return np.clip(np.floor(np.real(s) / ds).astype(int), 0, n_el - 1)


def _fold(rows, n_nodes):
    """Closed-end ghosts of theory §10.2 (varint.lattice.centreline.GHOST) folded into the real nodes: rows
    (..., K, n_nodes + 2) over nodes -1..N+1 (the dense layout of the numpy reference; the compiled kernels fold each
    stencil, k_fold_ghost)."""
    W = rows[..., 1:-1].copy()
    g0, gN = rows[..., 0], rows[..., -1]
    N = n_nodes - 1
    for c, coef in enumerate(GHOST):
        W[..., c] += coef * g0
        W[..., N - c] += coef * gN
    return W


def label_weights(s, n_nodes, ds, elements=None):
    """Dense Catmull-Rom weights W (..., K, n_nodes) with X(s_k) = W_k . r (any complex s; the element of each label
    from its real part, or ``elements``)."""
    s = np.asarray(s)
    e = _element_of(s, ds, n_nodes - 1) if elements is None else elements
    t = _over(s, ds) - e
    rows = np.zeros(s.shape + (n_nodes + 2,), dtype=np.result_type(s, float))
    val = _cr(t)
    np.put_along_axis(rows, np.broadcast_to(e, s.shape)[..., None] + np.arange(4), val, -1)
    return _fold(rows, n_nodes)


def _scatter_basis(out, e, coef):
    """out[..., e + i] += coef[..., i] for the four Catmull-Rom nodes e-1..e+2 (padded index e + i)."""
    idx = np.broadcast_to(e[..., None] + np.arange(4), coef.shape)
    np.put_along_axis(out, idx, np.take_along_axis(out, idx, -1) + coef, -1)


def label_weights_dd(s0, s1, n_nodes, ds):
    """Dense divided differences (N_i(s1) - N_i(s0))/(s1 - s0) (..., K, n_nodes), exact and cancellation-free: per
    element crossed, the polynomial divided difference between the piece's ends times the piece's share of the step.
    ``s0`` real (the level), ``s1`` possibly complex; the pieces from the real parts."""
    s0 = np.asarray(s0, dtype=float)
    s1 = np.asarray(s1)
    shape = np.broadcast_shapes(s0.shape, s1.shape)
    s0, s1 = np.broadcast_to(s0, shape), np.broadcast_to(s1, shape)
    n_el = n_nodes - 1
    e0 = _element_of(s0, ds, n_el)
    e1 = _element_of(s1, ds, n_el)
    out = np.zeros(shape + (n_nodes + 2,), dtype=np.result_type(s1, float))
    same = e0 == e1
    up = e1 > e0
    dsv = np.where(same, 1.0, s1 - s0)
    # the piece on the first element: from s0 to s1 (same element) or to the element's end the step leaves by
    a = s0 / ds - e0
    b = np.where(same, _over(s1, ds) - e0, np.where(up, 1.0, 0.0))
    frac = np.where(same, 1.0 / ds, (b - a) / dsv)
    _scatter_basis(out, e0, _cr_dd(a, b) * frac[..., None])
    if not np.all(same):
        # the piece on the last element, from the end the step enters by to s1
        a = np.where(up, 0.0, 1.0)
        b = _over(s1, ds) - e1
        frac = np.where(same, 0.0, (b - a) / dsv)
        _scatter_basis(out, e1, _cr_dd(a, b) * frac[..., None])
        for k in zip(*np.nonzero(np.abs(e1 - e0) > 1)):  # whole elements crossed in one step (rare)
            sign = 1.0 if up[k] else -1.0
            for e in range(min(e0[k], e1[k]) + 1, max(e0[k], e1[k])):
                lo, hi = (0.0, 1.0) if up[k] else (1.0, 0.0)
                out[k + (slice(e, e + 4),)] += _cr_dd(np.array(lo), np.array(hi)) * sign / dsv[k]
    return _fold(out, n_nodes)


# -- the step -------------------------------------------------------------------------------------------------------


class TubeEMStep:
    """Energy-momentum stepping of the coupled tube (docs/theory.md §12b); its own state (r, D, v, V, R, R', s, X, X',
    multipliers)."""

    def __init__(self, model, h, tol=1e-12, max_iter=40, body=True):
        why = em_rod.supports(model)
        if why:
            raise SolverError(why)
        rod, t = model.rod, model.tube
        self.model, self.rod, self.t = model, rod, t
        self.h, self.tol, self.max_iter = float(h), tol, max_iter
        self.body = bool(body)
        self.rate_refresh = 0.5  # chord: a new Jacobian when an update shrinks less than this
        #: the compiled loops (varint/schemes/em_tube_kernels.py: the fluid's pairs, the labels' constraint, the rod's discrete
        #: gradient); False: the numpy reference throughout
        self.compiled = True
        self.N, self.M, self.ds = rod.N, t.M, rod.ds
        n1 = self.N + 1
        self.constrained = bool(rod.constrained)
        self.Jd = rod.section.J
        self.Kd = np.zeros(3) if self.constrained else rod.section.K
        self.m, self.E = director_masses(rod)
        mbar = np.asarray(t.label_mass_all, dtype=float)
        self.mbar = mbar[1:-1].copy()  # interior labels (the unknown ones)
        self.m[0] += mbar[0]  # the end labels sit on the end nodes: X_0 = r_0, X_M = r_N (Catmull-Rom interpolates)
        self.m[-1] += mbar[-1]
        self.r, self.D, self.v = rod.r0.copy(), rod.Lam0.copy(), rod.v0 * rod.mask[:, :3]
        # a held node neither moves nor turns, whatever rod.initial says (as the midpoint's Legendre map)
        self.V = np.einsum("nij,njk->nik", self.D, _hat(rod.omega0 * rod.mask[:, 3:]) @ np.eye(3))
        self.lam = np.zeros((n1, 6))
        self.mu_rod = np.zeros((self.N, 3))
        if self.constrained:
            miss = float(np.max(np.abs(strains(self.r, self.D, self.ds)[1] - CHI)))
            if miss > 1e-9:
                raise SolverError(f"rod.constraint: the initial configuration misses Gamma = chi by {miss:.1e}")
        cfg = t.config(np.concatenate([t.q_init, t.lam_init]))
        self.s = np.asarray(cfg.s, dtype=float).copy()
        self.R = np.asarray(cfg.R, dtype=float).copy()
        self.wall = t.wall if t.has_wall else None
        #: the wall's radii are unknowns (any [wall]); with inertia a w_j (dynamic), or none (quasistatic: their rows
        #: are the wall's discrete-gradient balance, docs/theory.md §12b "A quasistatic wall")
        self.radii_unknown = bool(t.has_wall)
        self.dyn = bool(t.has_wall and t.wall_dynamic)
        self.aw = (t.wall.a * t.node_weights) if self.dyn else np.zeros(n1)
        self.w = np.asarray(t.node_weights, dtype=float)
        self.Rdot = np.zeros(n1)
        if self.dyn:
            self.Rdot = self._wall_rates(t)
        leg = model.initial_legendre()
        self.sdot = leg["sdot"][1:-1].copy()
        self.X = label_weights(self.s[1:-1], n1, self.ds) @ self.r
        self.Xdot = leg["Xdot"][1:-1].copy()
        self.nu = np.zeros((self.M - 1, 3))
        self.eos = t.eos
        self.incompressible = bool(t.incompressible)
        self.mk = np.asarray(t.m, dtype=float)
        self.Sk = np.asarray(t.S, dtype=float) if t.eos is not None else None
        #: [shock_capturing]: the viscous pressure Q_k(V^n, V^{n+1}) joins the parcels' pressures in the volumes'
        #: discrete gradient, and its work heats the parcels after each step (docs/theory.md §12b, "Shock capturing")
        self.shock = next((f for f in t.forces if isinstance(f, CoupledShockCapturing)), None)
        self.viscous_work = 0.0  #: the viscous work since t = 0 (J): what the shock capturing turned into heat
        self.V0 = np.asarray(t.V0, dtype=float) if self.incompressible else None
        self.mu_liq = np.zeros(self.M)
        self.p_ext = float(t.p_ext)
        self.g = np.asarray(rod.g, dtype=float)
        self.fext = self.m[:, None] * self.g[None, :]
        self.fext[-1] += rod.force
        # a dead tip torque: varint.schemes.em_rod.tip_torque_forces (J changes by exactly h T per step; its work summed)
        self.torque = np.asarray(rod.torque, dtype=float)
        self.has_torque = bool(np.any(self.torque))
        self.work = 0.0
        # supports (rod_em's): a pinned node keeps r, a clamped one also its directors and multipliers
        self.fix_r = np.zeros(n1, bool)
        self.fix_D = np.zeros(n1, bool)
        for node, kind in ((0, model.scene.rod.ends.s0), (self.N, model.scene.rod.ends.sL)):
            self.fix_r[node] |= kind in ("pinned", "clamped")
            self.fix_D[node] |= kind == "clamped"
        self.free = not (self.fix_r.any() or self.fix_D.any())
        # a free tube travels: its positions r, X are kept relative to a floating origin moved with node 0 after each
        # step on varint.terms.rod.ORIGIN_GRID (an exact subtraction), so that their rounding stays eps times the tube's
        # size, not eps times its distance from where it started (theory §12c; the midpoint's Simulation.floating_origin)
        self.floating_origin = self.free
        self.origin = np.zeros(3)
        self._layout()
        self.n = 0
        self._lu = None
        self._prev = None
        self._lvl = None
        self.last = dict(iterations=0, jacobians=0, fallback=0)
        self.stats = dict(iterations=0, jacobians=0, residuals=0)
        self._halvings = 0  # depth of varint.schemes.em_rod.halved_step's recursion
        if self.incompressible:
            # the liquid holds each parcel's volume at t = 0 (a constraint that jumped on the first step would be work
            # done by the pressures); data whose shape and reference volumes m/rho disagree beyond 1e-6 are refused
            V_init = self.volumes(self.s, self.R, self.r, self.D)
            miss = float(np.max(np.abs(V_init / self.V0 - 1.0)))
            if miss > 1e-6:
                raise SolverError(f"fluid: the parcels' volumes in the initial shape (rod.initial) differ from their reference volumes "
                                  f"m/rho by {miss:.1e} (relative); the energy-momentum step needs them equal to 1e-6")
            self.V0 = V_init

    def _wall_rates(self, t):
        """The initial wall rates R'_j: the tube's initial velocities mapped to the configuration (as its radii are)."""
        c = t.B @ np.concatenate([t.v_init, np.zeros(len(t.lam_init))])
        return np.asarray(c[t.index["R"]: t.index["R"] + t.nR], dtype=float).copy()

    # -- layout of the unknowns ------------------------------------------------------------------------------------

    def _layout(self):
        n1, M = self.N + 1, self.M
        sizes = [("dr", n1 * 3), ("dD", n1 * 9), ("lam", n1 * 6), ("mu_rod", self.N * 3 if self.constrained else 0),
                 ("dR", n1 if self.radii_unknown else 0), ("ds", M - 1), ("dX", (M - 1) * 3), ("nu", (M - 1) * 3),
                 ("mu_liq", M if self.incompressible else 0)]
        self.sl, o = {}, 0
        for name, n in sizes:
            self.sl[name] = slice(o, o + n)
            o += n
        self.nz = o
        # Newton's update size: positions and labels relative to L, radii to R0, directors as they are
        sc = np.full(o, np.inf)
        L = self.rod.L
        sc[self.sl["dr"]] = L
        sc[self.sl["dD"]] = 1.0
        sc[self.sl["dR"]] = self.t.R0
        sc[self.sl["ds"]] = L
        sc[self.sl["dX"]] = L
        self.scale = sc
        self.qmask = np.isfinite(sc)
        fixed = np.zeros(o, bool)
        fixed[self.sl["dr"]] = np.repeat(self.fix_r, 3)
        fixed[self.sl["dD"]] = np.repeat(self.fix_D, 9)
        fixed[self.sl["lam"]] = np.repeat(self.fix_D, 6)
        self.fixed = fixed
        # locations of the unknowns for the sparse Jacobian (:meth:`jacobian_sparse`), one per kind and place: node n's
        # dr, dD, lam, dR; element e's mu_rod; interior label k's ds, dX, nu; parcel k's mu_liq
        N = self.N
        first, o2 = {}, 0
        for name, count in (("dr", n1), ("dD", n1), ("lam", n1), ("dR", n1), ("mu_rod", N), ("ds", M - 1),
                            ("dX", M - 1), ("nu", M - 1), ("mu_liq", M)):
            first[name] = o2
            o2 += count
        self.loc_first, self.n_loc = first, o2
        loc = np.empty(o, int)
        for name, per in (("dr", 3), ("dD", 9), ("lam", 6), ("mu_rod", 3), ("dR", 1), ("ds", 1), ("dX", 3), ("nu", 3),
                          ("mu_liq", 1)):
            sl = self.sl[name]
            loc[sl] = first[name] + np.arange(sl.stop - sl.start) // per
        self.loc_of = loc
        self._colouring = {}
        self.stats_pattern = dict(checks=0, misses=0, colours=0)

    def unpack(self, z):
        """The blocks of z (leading batch axes kept)."""
        b = z.shape[:-1]
        n1, M = self.N + 1, self.M
        out = dict(dr=z[..., self.sl["dr"]].reshape(b + (n1, 3)), dD=z[..., self.sl["dD"]].reshape(b + (n1, 3, 3)),
                   lam=z[..., self.sl["lam"]].reshape(b + (n1, 6)),
                   ds=z[..., self.sl["ds"]], dX=z[..., self.sl["dX"]].reshape(b + (M - 1, 3)),
                   nu=z[..., self.sl["nu"]].reshape(b + (M - 1, 3)))
        out["mu_rod"] = z[..., self.sl["mu_rod"]].reshape(b + (self.N, 3)) if self.constrained else None
        out["dR"] = z[..., self.sl["dR"]] if self.radii_unknown else np.zeros(b + (n1,))
        out["mu_liq"] = z[..., self.sl["mu_liq"]] if self.incompressible else None
        return out

    def pack(self, dr, dD, lam, dR, ds, dX, nu, mu_rod=None, mu_liq=None):
        parts = [np.ravel(dr), np.ravel(dD), np.ravel(lam)]
        if self.constrained:
            parts.append(np.ravel(self.mu_rod if mu_rod is None else mu_rod))
        if self.radii_unknown:
            parts.append(np.ravel(dR))
        parts += [np.ravel(ds), np.ravel(dX), np.ravel(nu)]
        if self.incompressible:
            parts.append(np.ravel(self.mu_liq if mu_liq is None else mu_liq))
        return np.concatenate(parts).astype(float)

    # -- geometry at one level --------------------------------------------------------------------------------------

    def stretches(self, r, D):
        """Gamma_e (.., N, 3), |Gamma_e| (.., N) and the nodal stretch gamma_j (.., N+1) of theory §10.3."""
        G = strains(r, D, self.ds)[1]
        a = np.sqrt(np.sum(G * G, -1))  # sqrt of the sum of squares (not abs): complex steps pass through
        return G, a, nodal_stretch(a)

    def _pairs(self, s_lo, s_hi):
        """(parcel, element) pairs that parcels [s_lo_k, s_hi_{k+1}] may cover (real bounds)."""
        e_lo = _element_of(s_lo[:-1], self.ds, self.N)
        e_hi = _element_of(s_hi[1:], self.ds, self.N)
        count = e_hi - e_lo + 1
        k = np.repeat(np.arange(self.M), count)
        first = np.cumsum(count) - count  # each parcel's first pair
        return k, e_lo[k] + np.arange(len(k)) - first[k]

    def volumes(self, s, R, r, D):
        """Parcel volumes V_k at one level (theory §10.3; any leading batch axes on R, r, D, s)."""
        _, _, gam = self.stretches(r, D)
        s_re = np.real(s).reshape(-1, self.M + 1)
        pk, pe = self._pairs(s_re.min(0), s_re.max(0))
        return self._volumes_on(s, R, gam, pk, pe)

    def _volumes_on(self, s, R, gam, pk, pe):
        t_lo = _over(s[..., pk], self.ds) - pe
        t_hi = _over(s[..., pk + 1], self.ds) - pe
        last = pe == self.N - 1
        S = _moments(t_hi, last) - _moments(t_lo, last)  # (.., npairs, 4)
        Vp = self.ds * np.pi * np.sum(_triple(_ends(R, pe), _ends(gam, pe)) * S[..., _Q], (-3, -2, -1))
        return _scatter(Vp, pk, self.M)  # the pairs summed into their parcels

    # -- energies --------------------------------------------------------------------------------------------------

    def wall_energy(self, R):
        if self.wall is None:
            return 0.0
        w = self.wall
        if w.law == "linear":
            d = (R[..., 1:] - R[..., :-1]) / self.ds
            return 0.5 * w.beta1 * self.ds * np.sum(d * d, -1) + 0.5 * w.beta2 * np.sum(self.w * (R - self.t.R0) ** 2, -1)
        A = np.pi * R * R
        A0 = np.pi * self.t.R0 ** 2
        d = (A[..., 1:] - A[..., :-1]) / self.ds
        f = w.stiffness * (2.0 / 3.0 * A ** 1.5 / np.sqrt(A0) - A + A0 / 3.0)
        return 0.5 * w.tension * self.ds * np.sum(d * d, -1) + np.sum(self.w * f, -1)

    def wall_dd(self, R0, R1):
        """Discrete gradient of the wall energy in R (exact: quadratic pieces at the midpoint, the tube law's f(A) by
        the closed-form divided difference of A^(3/2) in sqrt(A))."""
        out = np.zeros(np.broadcast_shapes(np.shape(R0), np.shape(R1)), dtype=np.result_type(R0, R1))
        if self.wall is None:
            return out
        w = self.wall
        if w.law == "linear":
            Rb = 0.5 * (R0 + R1)
            d = (Rb[..., 1:] - Rb[..., :-1]) / self.ds
            out[..., 1:] += w.beta1 * d
            out[..., :-1] -= w.beta1 * d
            return out + w.beta2 * self.w * (Rb - self.t.R0)
        A0r = np.pi * self.t.R0 ** 2
        Aa, Ab = np.pi * R0 * R0, np.pi * R1 * R1
        dA_dR = np.pi * (R0 + R1)  # Delta A = pi (R0 + R1) Delta R, exact
        d0 = (Aa[..., 1:] - Aa[..., :-1]) / self.ds
        d1 = (Ab[..., 1:] - Ab[..., :-1]) / self.ds
        t = 0.5 * w.tension * (d0 + d1)  # Delta(1/2 T ds d^2) = T ds dbar Delta d, Delta d = (Delta A_b - Delta A_a)/ds
        gA = np.zeros_like(out)
        gA[..., 1:] += t
        gA[..., :-1] -= t
        a0, a1 = np.sqrt(Aa), np.sqrt(Ab)  # R > 0: sqrt(A) = sqrt(pi) R
        dd15 = (a0 * a0 + a0 * a1 + a1 * a1) / (a0 + a1)  # (A1^1.5 - A0^1.5)/(A1 - A0)
        gA += self.w * w.stiffness * (2.0 / 3.0 * dd15 / np.sqrt(A0r) - 1.0)
        return gA * dA_dR

    def potential(self, r, D, R, s, X):
        """U(q) of one level (for the energy monitor and the tests' discrete-gradient identity)."""
        U = potential(r, D, self.ds, self.Jd, self.Kd) + self.wall_energy(R)
        V = self.volumes(s, R, r, D)
        if self.eos is not None:
            U = U + np.sum(self.eos.psi(V, self.mk, self.Sk), -1)
        U = U + self.p_ext * np.sum(V, -1)
        return U - np.sum(self.fext * r, (-1, -2)) - np.sum(self.mbar[:, None] * self.g * X, (-1, -2))

    # -- the residual ------------------------------------------------------------------------------------------------

    def _levels(self, z):
        u = self.unpack(z)
        s1 = np.concatenate([np.broadcast_to(self.s[0], u["ds"].shape[:-1] + (1,)), self.s[1:-1] + u["ds"],
                             np.broadcast_to(self.s[-1], u["ds"].shape[:-1] + (1,))], -1)
        return u, self.r + u["dr"], self.D + u["dD"], self.R + u["dR"], s1, self.X + u["dX"]

    def _level0(self):
        """The level's own quantities, the same for every residual of a step (stretches, label weights, frame
        nodes and their directors), kept while the level's arrays are the same objects (a step and a restore put
        new ones in place; nothing changes them in place)."""
        key = (self.r, self.D, self.s, self.R)
        c = self._lvl
        if c is None or any(a is not b for a, b in zip(c["key"], key)):
            G0, a0, gam0 = self.stretches(self.r, self.D)
            fr = np.clip(np.rint(self.s[1:-1] / self.ds).astype(int), 0, self.N)
            c = dict(key=key, G0=G0, a0=a0, gam0=gam0, fr=fr, De0=self.D[fr],
                     W0=label_weights(self.s[1:-1], self.N + 1, self.ds), pairs={})
            self._lvl = c
        return c

    def _pairs0(self, lvl, pk, pe):
        """Per (parcel, element) pair at the level (cached with :meth:`_level0`): V0, S0, the label coordinates,
        the radii and nodal stretches at the element's ends."""
        key = (pk.tobytes(), pe.tobytes())
        out = lvl["pairs"].get(key)
        if out is None:
            ds = self.ds
            tl0, th0 = self.s[pk] / ds - pe, self.s[pk + 1] / ds - pe
            last = pe == self.N - 1
            out = dict(V0=self._volumes_on(self.s, self.R, lvl["gam0"], pk, pe),
                       S0=np.ascontiguousarray(_moments(th0, last) - _moments(tl0, last)),
                       tl0=tl0, th0=th0, R0p=_ends(self.R, pe), G0p=_ends(lvl["gam0"], pe))
            lvl["pairs"][key] = out
        return out

    def fluid_discrete_gradient(self, z, gam1=None):
        """Parcel volumes at both levels and the discrete gradient of sum_k c_k V_k in (s, R, |Gamma_e|), with
        c_k = dpsi_k (the divided difference of psi) + p_ext - mu_k.  Returns dict(V0, V1, c, gs (.., M-1), gR (.., N+1),
        gG (.., N): the coefficient of Delta|Gamma_e|).  ``gam1``: the nodal stretches at z's level if known."""
        u, r1, D1, R1, s1, _ = self._levels(z)
        lvl = self._level0()
        if gam1 is None:
            _, _, gam1 = self.stretches(r1, D1)
        s1_re = np.real(s1).reshape(-1, self.M + 1)  # every row of a batch: the pairs cover them all
        pk, pe = self._pairs(np.minimum(self.s, s1_re.min(0)), np.maximum(self.s, s1_re.max(0)))
        p0 = self._pairs0(lvl, pk, pe)
        V0 = p0["V0"]
        b = s1.shape[:-1]
        if self.compiled:  # the per-pair loops compiled (varint/schemes/em_tube_kernels.py), on the batch's rows
            dt = np.result_type(s1, R1, gam1, z)  # the new level's quantities all come from z
            s1r, R1r = _batch_rows(s1, b, (self.M + 1,), dt), _batch_rows(R1, b, (self.N + 1,), dt)
            g1r = _batch_rows(gam1, b, (self.N + 1,), dt)
            V1 = np.empty((s1r.shape[0], self.M), dtype=dt)
            kernels.pair_volumes(s1r, R1r, g1r, pk, pe, self.ds, V1)
            V1 = V1.reshape(b + (self.M,))
        else:
            V1 = self._volumes_on(s1, R1, gam1, pk, pe)
        if self.eos is not None:
            psi = lambda V: self.eos.psi(V, self.mk, self.Sk)  # noqa: E731
            dpsi = lambda V: self.eos.dpsi(V, self.mk, self.Sk)[0]  # noqa: E731
            c = scalar_dd(psi, dpsi, V0, V1)
        else:
            c = np.zeros(V1.shape, dtype=V1.dtype)
        c = c + self.p_ext
        if self.incompressible:
            c = c - u["mu_liq"]
        if self.shock is not None:  # the viscous pressure acts with the gas's own (psi' = -p)
            c = c - self._viscous_pressure(V0, V1)
        if self.compiled:
            B = s1r.shape[0]
            gs, gR, gg = np.empty((B, self.M + 1), dt), np.empty((B, self.N + 1), dt), np.empty((B, self.N + 1), dt)
            kernels.pair_gradients(self.s, s1r, self.R, R1r, lvl["gam0"], g1r, pk, pe, _batch_rows(c, b, (self.M,), dt),
                                   p0["S0"], self.ds, gs, gR, gg)
            return self._fluid_out(V0, V1, c, gs.reshape(b + (-1,)), gR.reshape(b + (-1,)), gg.reshape(b + (-1,)))
        cp = c[..., pk]  # per pair
        ds = self.ds
        # S parts (label coordinates) and their exact divided differences, per pair
        tl0, th0 = p0["tl0"], p0["th0"]
        tl1, th1 = _over(s1[..., pk], ds) - pe, _over(s1[..., pk + 1], ds) - pe
        S0 = p0["S0"]
        last = pe == self.N - 1
        S1 = _moments(th1, last) - _moments(tl1, last)
        Sb = 0.5 * (S0 + S1)
        ddh, ddl = _moment_dd(th0, th1, last), _moment_dd(tl0, tl1, last)
        # P_(ijl) = R_i R_j gamma_l on the pair's element (i, j, l in {0, 1}: its two nodes), q = i + j + l
        R0p, R1p = p0["R0p"], _ends(R1, pe)
        G0p, G1p = p0["G0p"], _ends(gam1, pe)
        Pb = 0.5 * (_triple(R0p, G0p) + _triple(R1p, G1p))
        g_hi = np.sum(Pb * ddh[..., _Q], (-3, -2, -1))
        g_lo = -np.sum(Pb * ddl[..., _Q], (-3, -2, -1))
        # Delta P = Delta R_i avf(R_j, g_l) + Delta R_j avf(R_i, g_l) + Delta g_l avf(R_i, R_j); S_q symmetric in i, j
        SbQ = Sb[..., _Q]
        gRp = 2.0 * np.sum(SbQ * _avf2(R0p[..., None, :, None], R1p[..., None, :, None], G0p[..., None, None, :],
                                       G1p[..., None, None, :]), (-2, -1))
        gGp = np.sum(SbQ * _avf2(R0p[..., :, None, None], R1p[..., :, None, None], R0p[..., None, :, None],
                                 R1p[..., None, :, None]), (-3, -2))
        k = np.pi * cp  # ds pi c_k; the label rows carry 1/ds from t = s/ds - e
        g_hi, g_lo = k * g_hi, k * g_lo
        gRp, gGp = ds * k[..., None] * gRp, ds * k[..., None] * gGp
        n1 = self.N + 1
        # the pairs summed into labels k, k + 1 and nodes e, e + 1
        gs = _scatter(np.concatenate([g_lo, g_hi], -1), np.concatenate([pk, pk + 1]), self.M + 1)
        gR = _scatter(np.concatenate([gRp[..., 0], gRp[..., 1]], -1), np.concatenate([pe, pe + 1]), n1)
        gg = _scatter(np.concatenate([gGp[..., 0], gGp[..., 1]], -1), np.concatenate([pe, pe + 1]), n1)
        return self._fluid_out(V0, V1, c, gs, gR, gg)

    def _viscous_pressure(self, V0, V1):
        """Q_k(V^n, V^{n+1}) of the shock capturing (varint.terms.shock_capturing.viscous_pressure_q; complex-safe, the
        Jacobian's complex steps pass through it), with the coupled tube's compression rate (level n's mean
        cross-section, or pi R0^2 in a rigid tube: CoupledShockCapturing.cross_sections)."""
        f = self.shock
        A = f.cross_sections(self.s, V0)
        K = np.exp(self.Sk / f.cv) * self.mk ** f.gamma
        return viscous_pressure_q(V0, V1, self.mk, K, f.gamma, A, self.h, f.cQ, f.cL)

    def _heat(self, u):
        """Raise each parcel's entropy by the viscous work of the accepted step, W_k = -Q_k (V^{n+1} - V^n) >= 0 at
        V^{n+1}: the internal energy gains exactly what the viscous pressure took from the motion."""
        s1 = self.s.copy()
        s1[1:-1] += u["ds"]
        V0 = self.volumes(self.s, self.R, self.r, self.D)
        V1 = self.volumes(s1, self.R + u["dR"], self.r + u["dr"], self.D + u["dD"])
        f = self.shock
        W = np.maximum(-np.real(self._viscous_pressure(V0, V1)) * (V1 - V0), 0.0)  # (the max guards round-off)
        K = np.exp(self.Sk / f.cv) * self.mk ** f.gamma
        self.Sk[:] = heated_entropy(self.Sk, V1, K, W, f.gamma, f.cv)
        self.viscous_work += float(np.sum(W))

    @staticmethod
    def _fluid_out(V0, V1, c, gs, gR, gg):
        """fluid_discrete_gradient's result from the scattered gradients (gs on all labels, gg on the nodal stretches)."""
        # nodal stretch -> element stretches: gamma_0 = |G_0|, gamma_N = |G_(N-1)|, else the mean of the two
        gG = 0.5 * (gg[..., :-1] + gg[..., 1:])
        gG[..., 0] += 0.5 * gg[..., 0]
        gG[..., -1] += 0.5 * gg[..., -1]
        return dict(V0=V0, V1=V1, c=c, gs=gs[..., 1:-1], gR=gR, gG=gG)

    def label_constraint(self, u, r1, D1, s1, X1):
        """c_k(q_1) and the discrete derivative's forces on (r, D, s, X) from nu (theory §12b)."""
        n1 = self.N + 1
        sk0, sk1 = self.s[1:-1], s1[..., 1:-1]
        lvl = self._level0()
        e = lvl["fr"]
        if self.compiled:  # the per-label loops compiled (varint/schemes/em_tube_kernels.py), on the batch's rows
            return self._label_constraint_compiled(u["nu"], r1, D1, s1, X1, e)
        W0 = lvl["W0"]
        W1 = label_weights(sk1, n1, self.ds)
        De0, De1 = lvl["De0"], D1[..., e, :, :]
        c1 = np.einsum("...kji,...kj->...ki", De1, X1 - np.einsum("...kn,...nc->...kc", W1, r1))
        nu = u["nu"]
        Db = 0.5 * (De0 + De1)
        Wb = 0.5 * (W0 + W1)
        rb = 0.5 * (self.r + r1)
        Xb = 0.5 * (self.X + X1)
        Dnu = np.einsum("...kij,...kj->...ki", Db, nu)
        FX = Dnu
        Fr = -np.einsum("...ki,...kc->...ic", Wb, Dnu)
        xk = Xb - np.einsum("...kn,...nc->...kc", Wb, rb)
        FD = np.zeros(r1.shape[:-1] + (3, 3), dtype=np.result_type(r1, nu, D1))
        self._add_frames(FD, e, xk[..., :, None] * nu[..., None, :])
        # y_i = D_e^T r_i at both levels; F_s = -sum_i DD_i ybar_i . nu = -(1/2) sum_l (DD r_l) . (D_e^l nu), l = 0, 1
        DD = label_weights_dd(sk0, sk1, n1, self.ds)
        Fs = -0.5 * (np.einsum("...kj,kji,...ki->...k", np.einsum("...kn,nj->...kj", DD, self.r), De0, nu)
                     + np.einsum("...kj,...kji,...ki->...k", np.einsum("...kn,...nj->...kj", DD, r1), De1, nu))
        return c1, Fr, FD, Fs, FX

    def _rod_dg_compiled(self, r1, D1, stress):
        n1 = self.N + 1
        b = r1.shape[:-2]
        dt = np.result_type(r1, D1, stress)
        r1r, D1r = _batch_rows(r1, b, (n1, 3), dt), _batch_rows(D1, b, (n1, 3, 3), dt)
        str_r = _batch_rows(stress, b, (self.N, 3), dt)
        B = r1r.shape[0]
        Fr, FD = np.empty((B, n1, 3), dt), np.empty((B, n1, 3, 3), dt)
        rod_discrete_gradient(self.r[None], self.D[None], r1r, D1r, self.ds, self.Jd, self.Kd, str_r, Fr, FD)
        return Fr.reshape(b + (n1, 3)), FD.reshape(b + (n1, 3, 3))

    def _label_constraint_compiled(self, nu, r1, D1, s1, X1, fr):
        n1, K = self.N + 1, self.M - 1
        b = s1.shape[:-1]
        dt = np.result_type(nu, r1, D1, s1, X1)
        r1r, D1r = _batch_rows(r1, b, (n1, 3), dt), _batch_rows(D1, b, (n1, 3, 3), dt)
        s1r = _batch_rows(s1, b, (self.M + 1,), dt)
        X1r, nur = _batch_rows(X1, b, (K, 3), dt), _batch_rows(nu, b, (K, 3), dt)
        B = r1r.shape[0]
        c1, Fs, FX = np.empty((B, K, 3), dt), np.empty((B, K), dt), np.empty((B, K, 3), dt)
        Fr, FD = np.empty((B, n1, 3), dt), np.empty((B, n1, 3, 3), dt)
        kernels.label_constraint(self.r, self.D, self.X, self.s, fr, r1r, D1r, s1r, X1r, nur, self.ds, c1, Fr, FD,
                                 Fs, FX)
        return (c1.reshape(b + (K, 3)), Fr.reshape(b + (n1, 3)), FD.reshape(b + (n1, 3, 3)), Fs.reshape(b + (K,)),
                FX.reshape(b + (K, 3)))

    @staticmethod
    def _add_frames(FD, e, vals):
        for kk, node in enumerate(e):
            FD[..., node, :, :] += vals[..., kk, :, :]

    def residual(self, z):
        """R(z) (.., nz) from the current level; z the increments and multipliers (layout :meth:`unpack`)."""
        h = self.h
        u, r1, D1, R1, s1, X1 = self._levels(z)
        lvl = self._level0()
        G1, a1, gam1 = self.stretches(r1, D1)
        fl = self.fluid_discrete_gradient(z, gam1)
        # the fluid reaches the rod through |Gamma_e|: a stress gG_e/ds along (Gamma^0 + Gamma^1)/(|Gamma^0| + |Gamma^1|)
        G0, a0 = lvl["G0"], lvl["a0"]
        ghat = (G0 + G1) / (a0 + a1)[..., None]
        stress = (fl["gG"] / self.ds)[..., None] * ghat
        if u["mu_rod"] is not None:
            stress = stress + u["mu_rod"]
        if self.compiled:
            Fr, FD = self._rod_dg_compiled(r1, D1, stress)
        else:
            Fr, FD = discrete_gradient(self.r, self.D, r1, D1, self.ds, self.Jd, self.Kd, stress)
        c1, Fr_c, FD_c, Fs_c, FX_c = self.label_constraint(u, r1, D1, s1, X1)
        lam = u["lam"]
        Db = 0.5 * (self.D + D1)
        Sm = np.stack([np.stack([2 * lam[..., 0], lam[..., 3], lam[..., 4]], -1),
                       np.stack([lam[..., 3], 2 * lam[..., 1], lam[..., 5]], -1),
                       np.stack([lam[..., 4], lam[..., 5], 2 * lam[..., 2]], -1)], -2)
        Rr = (2.0 / h) * self.m[:, None] * (u["dr"] - h * self.v) + h * (Fr + Fr_c - self.fext)
        RD = (2.0 / h) * self.E[:, None, :] * (u["dD"] - h * self.V) + h * (FD + FD_c + Db @ Sm)
        if self.has_torque:
            RD[..., -1, :, :] -= h * tip_torque_forces(Db[..., -1, :, :], self.torque)
        C = _T(D1) @ D1
        Rl = np.stack([C[..., i, j] - (1.0 if i == j else 0.0) for i, j in _PAIRS], -1)
        b = z.shape[:-1]
        parts = [Rr.reshape(b + (-1,)), RD.reshape(b + (-1,)), Rl.reshape(b + (-1,))]
        if self.constrained:
            parts.append((strains(r1, D1, self.ds)[1] - CHI).reshape(b + (-1,)))
        if self.radii_unknown:  # (a quasistatic wall: aw = 0, the row is the wall's discrete-gradient balance)
            parts.append((2.0 / h) * self.aw * (u["dR"] - h * self.Rdot) + h * (self.wall_dd(self.R, R1) + fl["gR"]))
        parts.append(h * (fl["gs"] + Fs_c))
        parts.append(((2.0 / h) * self.mbar[:, None] * (u["dX"] - h * self.Xdot) + h * (FX_c - self.mbar[:, None] * self.g)).reshape(b + (-1,)))
        parts.append(c1.reshape(b + (-1,)))
        if self.incompressible:
            parts.append(fl["V1"] - self.V0)
        out = np.concatenate(parts, -1)
        if np.any(self.fixed):
            out[..., self.fixed] = z[..., self.fixed]
        return out

    # -- Newton ------------------------------------------------------------------------------------------------------

    def jacobian(self, z, chunk=64, body=False):
        """Dense Jacobian by complex step (exact to round-off), in batches of ``chunk`` columns (the reference for
        :meth:`jacobian_sparse`, and its fallback); with ``body`` T^T J T."""
        n = self.nz
        J = np.empty((n, n))
        eps = 1e-30
        for a in range(0, n, chunk):
            cols = np.arange(a, min(n, a + chunk))
            E = np.zeros((len(cols), n))
            E[np.arange(len(cols)), cols] = 1.0
            if body:
                E = self._rotate(E)
            Rc = self.residual(z[None, :] + 1j * eps * E).imag / eps
            J[:, cols] = (self._rotate(Rc, transpose=True) if body else Rc).T
            self.stats["residuals"] += len(cols)
        return J

    # -- the sparse Jacobian ------------------------------------------------------------------------------------------

    def _cliques(self, z):
        """The Jacobian's pattern by location (:meth:`_layout`) at the real iterate z, as blocks (rows, cols, hub):
        the rows of every location in ``rows`` may read the columns of every location in ``cols`` (hub False), or
        (hub True) the locations in ``cols`` read all of ``rows`` and all of ``rows`` read ``cols`` (a star):

        * each node's D and lam (the orthonormality rows, the multipliers' forces); each element's nodes' r, D and
          mu_rod (the discrete gradient, the strain constraint, the fluid's stress direction); the wall's
          neighbouring radii;
        * each label's constraint, a star: its s, X, nu and its frame node's D read, and are read by, the r of the
          Catmull-Rom nodes e-1..e+2 of every element between its two levels (the nodes' forces -W^T D_e nu read
          no other node, and no r reads another through the label);
        * each (parcel, element) pair of the volumes, a star: the s of labels k, k+1, the radii of nodes e, e+1 and
          the parcel's multiplier read, and are read by, the r and D of nodes e-1..e+2 (the nodal stretch reads the
          elements on both sides; the stretch's coefficient reads no stretch); for a gas or barotropic liquid all
          pairs of a parcel in one full block instead (psi's divided difference reads the whole parcel's volume).

        The elements and pairs are those of the real parts, as the residual finds them (the complex step does not
        move them)."""
        N, M, ds, f = self.N, self.M, self.ds, self.loc_first

        def nodes(kind, a, b):
            return tuple(range(f[kind] + max(a, 0), f[kind] + min(b, N) + 1))

        s0 = self.s
        s1 = s0.copy()
        s1[1:-1] += np.real(z[self.sl["ds"]])
        full = [(f["dD"] + n, f["lam"] + n) for n in range(N + 1)] + [(f["dR"] + n,) for n in range(N + 1)]
        full += [(f["dr"] + e, f["dr"] + e + 1, f["dD"] + e, f["dD"] + e + 1, f["mu_rod"] + e) for e in range(N)]
        full += [(f["dR"] + e, f["dR"] + e + 1) for e in range(N)]
        out = [(c, c, False) for c in full]
        fr = np.clip(np.rint(s0[1:-1] / ds).astype(int), 0, N)
        e0, e1 = _element_of(s0[1:-1], ds, N), _element_of(s1[1:-1], ds, N)
        for kk in range(M - 1):
            lo, hi = min(e0[kk], e1[kk]), max(e0[kk], e1[kk])
            hub = (f["ds"] + kk, f["dX"] + kk, f["nu"] + kk, f["dD"] + fr[kk])
            out.append((nodes("dr", lo - 1, hi + 2), hub, True))
        pk, pe = self._pairs(np.minimum(s0, s1), np.maximum(s0, s1))
        per_parcel = [set() for _ in range(M)]
        for k, e in zip(pk, pe):
            hub = (nodes("dR", e, e + 1) + (f["mu_liq"] + k,) + ((f["ds"] + k - 1,) if k >= 1 else ())
                   + ((f["ds"] + k,) if k <= M - 2 else ()))
            if self.eos is not None:
                per_parcel[k].update(nodes("dr", e - 1, e + 2) + nodes("dD", e - 1, e + 2) + hub)
            else:
                out.append((nodes("dr", e - 1, e + 2) + nodes("dD", e - 1, e + 2), hub, True))
        if self.eos is not None:
            out += [(tuple(sorted(c)), tuple(sorted(c)), False) for c in per_parcel]
        return tuple(out)

    def _plan(self, z):
        """(colour of each column, number of colours, rows, cols of the pattern) for the pattern at z (cached): a
        greedy colouring of the locations (largest first), each location's unknowns on distinct colours, two
        locations on disjoint colours when some row location reads both."""
        key = self._cliques(z)
        plan = self._colouring.get(key)
        if plan is not None:
            return plan
        # the location pattern P (sparse: each block touches a bounded stencil, so building it, the conflict graph
        # P^T P and the colouring cost O(locations), not the O(locations^3) of a dense product)
        pr, pc = [], []
        for rows, cols, hub in key:
            rows, cols = np.asarray(rows, np.int64), np.asarray(cols, np.int64)
            if hub:
                allr = np.concatenate([rows, cols])
                pr += [np.repeat(allr, len(cols)), np.tile(cols, len(allr))]
                pc += [np.tile(cols, len(allr)), np.repeat(allr, len(cols))]
            else:
                pr.append(np.repeat(rows, len(cols)))
                pc.append(np.tile(cols, len(rows)))
        pr, pc = np.concatenate(pr), np.concatenate(pc)
        P = sp.csr_matrix((np.ones(len(pr), np.int64), (pr, pc)), shape=(self.n_loc, self.n_loc))
        P.sum_duplicates()
        P.data[:] = 1
        conflict = (P.T @ P).tocsr()
        size = np.bincount(self.loc_of, minlength=self.n_loc)
        order = np.argsort(self.loc_of, kind="stable")
        starts = np.concatenate([[0], np.cumsum(size)])
        colour = np.full(self.nz, -1)
        loc_col = [None] * self.n_loc
        for a in np.argsort(-size, kind="stable"):
            if size[a] == 0:
                continue
            busy = set()
            for b in conflict.indices[conflict.indptr[a]:conflict.indptr[a + 1]]:
                if loc_col[b] is not None:
                    busy.update(loc_col[b])
            free, c = [], 0
            while len(free) < size[a]:
                if c not in busy:
                    free.append(c)
                c += 1
            loc_col[a] = free
            colour[order[starts[a]:starts[a + 1]]] = free
        Pz = P[self.loc_of][:, self.loc_of].tocoo()
        rows, cols = Pz.row, Pz.col
        plan = (colour, int(colour.max()) + 1, rows, cols)
        if len(self._colouring) > 256:
            self._colouring.clear()
        self._colouring[key] = plan
        return plan

    def _rotate(self, x, transpose=False):
        """T x (or T^T x) over the last axis: the rod's dr_n, dD_n and the labels' dX_k turned by the level's
        directors (D_n, D_n (x) I, D_e of the label's frame node); the rest (multipliers, R, s, nu) as they are."""
        D = _T(self.D) if transpose else self.D
        n1, b = self.N + 1, x.shape[:-1]
        out = x.copy()
        sl = self.sl["dr"]
        out[..., sl] = np.einsum("nab,...nb->...na", D, x[..., sl].reshape(b + (n1, 3))).reshape(b + (-1,))
        sl = self.sl["dD"]
        out[..., sl] = (D @ x[..., sl].reshape(b + (n1, 3, 3))).reshape(b + (-1,))
        if self.M > 1:
            fr = np.clip(np.rint(self.s[1:-1] / self.ds).astype(int), 0, self.N)
            sl = self.sl["dX"]
            xk = x[..., sl].reshape(b + (self.M - 1, 3))
            out[..., sl] = np.einsum("kab,...kb->...ka", D[fr], xk).reshape(b + (-1,))
        return out

    def jacobian_sparse(self, z, body=False):
        """Sparse Jacobian by complex step with a colouring of the columns (:meth:`_plan`): one batched residual per
        colour.  With ``body``, T^T J T (:meth:`_rotate`: Newton's matrix in the level's body frames, which does not
        turn with a rigidly turning tube, so a factorisation survives across the steps of a spinning tube as
        varint.schemes.em_rod.RodEMStep's does); T is block-diagonal by location and the pattern is by location, so the
        colouring separates T's columns too.  A random direction rides in the same batch: its directional
        derivative must match J w row by row, else the pattern missed an entry, the miss is counted and the dense
        complex-step Jacobian used instead (never a silently dropped entry)."""
        colour, nc, rows, cols = self._plan(z)
        n, eps = self.nz, 1e-30
        w = np.random.default_rng(self.n + 12345).standard_normal(n)
        E = np.zeros((nc + 1, n))
        E[colour, np.arange(n)] = 1.0
        E[-1] = w
        if body:
            E = self._rotate(E)
        Rc = self.residual(z[None, :] + 1j * eps * E).imag / eps
        self.stats["residuals"] += nc + 1
        if body:
            Rc = self._rotate(Rc, transpose=True)
        J = sp.csr_matrix((Rc[colour[cols], rows], (rows, cols)), shape=(n, n))
        ref = Rc[-1]
        err = np.abs(J @ w - ref)
        scale = abs(J) @ np.abs(w)
        self.stats_pattern["checks"] += 1
        self.stats_pattern["colours"] = nc
        if np.all(err <= 1e-8 * scale + 1e-13 * scale.max()):
            return J
        self.stats_pattern["misses"] += 1
        return sp.csr_matrix(self.jacobian(z, body=body))

    def _factor(self, z):
        J = self.jacobian_sparse(z, body=self.body)
        rs = abs(J).max(axis=1).toarray().ravel()
        rs[rs == 0] = 1.0
        Jr = sp.diags(1.0 / rs) @ J
        cs = abs(Jr).max(axis=0).toarray().ravel()
        cs[cs == 0] = 1.0
        Jr = (Jr @ sp.diags(1.0 / cs)).tocsc()
        if not np.all(np.isfinite(Jr.data)):
            raise SolverError(f"step {self.n + 1}: non-finite Newton matrix")
        try:
            lu = spla.splu(Jr)
        except RuntimeError as exc:  # SuperLU: "Factor is exactly singular"
            raise SolverError(f"step {self.n + 1}: singular Newton matrix ({exc})") from None
        self.stats["jacobians"] += 1
        return lu, rs, cs

    def _update(self, R):
        lu, rs, cs = self._lu
        if self.body:
            R = self._rotate(R, transpose=True)
        du = lu.solve(-R / rs) / cs
        return self._rotate(du) if self.body else du

    def _outside(self, z):
        """Why z's level lies outside the tube's domain (labels not increasing inside [0, L], a radius not positive), or
        None."""
        u = self.unpack(z)
        s1 = self.s[1:-1] + u["ds"]
        if np.any(np.diff(np.concatenate([[self.s[0]], s1, [self.s[-1]]])) <= 0):
            return "leaves the labels' order or the tube (a parcel of zero or negative length)"
        if np.any(self.R + u["dR"] <= 0):
            return "has a radius <= 0"
        return None

    def _solve(self, z, chord):
        """varint.schemes.em_rod.chord_newton with this step's residual, equilibrated factorisation and domain guard."""
        sc, qm = self.scale, self.qmask
        return chord_newton(self, z, chord, self.residual, self._factor, self._update,
                            lambda dz: float(np.max(np.abs(dz[qm]) / sc[qm])), self._outside)

    def _predict_rigid(self):
        from ..lattice.lie import cay

        W = self.body_angular_velocity()
        return self.pack(self.h * self.v, self.D @ cay(self.h * W) - self.D, self.lam, self.h * self.Rdot,
                         self.h * self.sdot, self.h * self.Xdot, self.nu)

    def _predict(self):
        if self._prev is None:
            return self._predict_rigid()
        dr, Dp, dR, ds, dX = self._prev
        return self.pack(dr, self.D @ (_T(Dp) @ self.D) - self.D, self.lam, dR, ds, dX, self.nu)

    def _momentum_residuals(self, z):
        """The step's linear and angular momentum balances from their closed forms (the internal and constraint
        forces' sums vanish identically, theory §12a): the inertial and load terms of the rod's and the labels' rows
        only, so they carry the round-off of the momenta, not that of the stiff forces."""
        h = self.h
        u = self.unpack(z)
        rb, Db, Xb = self.r + 0.5 * u["dr"], self.D + 0.5 * u["dD"], self.X + 0.5 * u["dX"]
        fr = (2.0 / h) * self.m[:, None] * (u["dr"] - h * self.v) - h * self.fext
        fD = (2.0 / h) * self.E[:, None, :] * (u["dD"] - h * self.V)
        if self.has_torque:
            fD[-1] -= h * tip_torque_forces(Db[-1], self.torque)
        fX = (2.0 / h) * self.mbar[:, None] * (u["dX"] - h * self.Xdot) - h * self.mbar[:, None] * self.g
        P = fr.sum(0) + fX.sum(0)
        J = (np.cross(rb, fr).sum(0) + np.cross(np.swapaxes(Db, 1, 2), np.swapaxes(fD, 1, 2)).sum((0, 1))
             + np.cross(Xb, fX).sum(0))
        return P, J, rb, Db, Xb

    def _polish_rigid(self, z):
        """One correction of the solution in the six rigid directions (dr += a + w x rbar, dd_i += w x dbar_i,
        dX += a + w x Xbar) that zeroes the momentum balances of :meth:`_momentum_residuals`, as
        varint.schemes.em_rod.RodEMStep._polish_rigid: Newton's last update leaves the full residual at its floor, and in the
        body frames the chord matrix is not the exact one in the rigid directions, so the momenta would keep that
        floor (~1e-14 |J|) instead of the momenta's round-off.  The correction is of the floor's size."""
        P, J, rb, Db, Xb = self._momentum_residuals(z)
        # the labels are point masses of their own (their X moves rigidly with the rod's nodes)
        a, w = rigid_correction(self.h, P, J, np.concatenate([self.m, self.mbar]), np.concatenate([rb, Xb]), self.E, Db)
        d = np.swapaxes(Db, 1, 2)
        z = z.copy()
        z[self.sl["dr"]] += (a + np.cross(w, rb)).ravel()
        z[self.sl["dD"]] += np.swapaxes(np.cross(w, d), 1, 2).reshape(-1)
        z[self.sl["dX"]] += (a + np.cross(w, Xb)).ravel()
        return z

    def body_angular_velocity(self):
        return body_angular_velocity(self.D, self.V)

    def step(self):
        """Advance one step; returns the Newton iterations (:func:`varint.schemes.em_rod.em_step`: chord Newton from the
        predictor, full Newton on failure from the predictor and from a rigid motion, then
        :func:`varint.schemes.em_rod.halved_step`, docs/theory.md §12c)."""
        return em_step(self, (self._predict, self._predict_rigid))

    def _advance(self, z, it):
        """Take Newton's solution z as the step: held unknowns, the rigid polish, the new level and its velocities."""
        h = self.h
        z[self.fixed] = 0.0
        if self.free:
            z = self._polish_rigid(z)
        u = self.unpack(z)
        if self.has_torque:
            self.work += float(np.sum(tip_torque_forces(self.D[-1] + 0.5 * u["dD"][-1], self.torque) * u["dD"][-1]))
        if self.shock is not None:
            self._heat(u)
        self.v = 2.0 * u["dr"] / h - self.v
        self.V = 2.0 * u["dD"] / h - self.V
        self.Xdot = 2.0 * u["dX"] / h - self.Xdot
        self.sdot = 2.0 * u["ds"] / h - self.sdot  # the predictor's label rate (s has no inertia of its own)
        if self.dyn:
            self.Rdot = 2.0 * u["dR"] / h - self.Rdot
        self._prev = (u["dr"].copy(), self.D, u["dR"].copy(), u["ds"].copy(), u["dX"].copy())
        self.r, self.D = self.r + u["dr"], self.D + u["dD"]
        self.R = self.R + u["dR"]
        self.s = self.s.copy()
        self.s[1:-1] += u["ds"]
        self.X = self.X + u["dX"]
        self.lam, self.nu = u["lam"].copy(), u["nu"].copy()
        if self.constrained:
            self.mu_rod = u["mu_rod"].copy()
        if self.incompressible:
            self.mu_liq = u["mu_liq"].copy()
        W = self.body_angular_velocity()
        self.V[:, :, 0] = np.einsum("nij,nj->ni", self.D, np.cross(W, CHI))
        if self.floating_origin:
            shift = origin_shift(self.r[0])
            self.r, self.X, self.origin = self.r - shift, self.X - shift, self.origin + shift
        self.n += 1
        self.stats["iterations"] += it

    def _guess_over(self, before):
        """The step's unknowns from the level in ``before`` (:meth:`state_data`) to the current one: increments and
        the current multipliers (varint.schemes.em_rod.halved_step's start for Newton at h)."""
        old = {k: np.asarray(before[f"tem_{k}"], dtype=float).reshape(np.shape(getattr(self, k)))
               for k in ("r", "D", "R", "s", "X")}
        moved = self.origin - before["tem_origin"]  # the floating origin's moves since
        return self.pack(self.r + moved - old["r"], self.D - old["D"], self.lam, self.R - old["R"],
                         (self.s - old["s"])[1:-1], self.X + moved - old["X"], self.nu)

    def _prev_of(self, z):
        """The predictor's data (the last increments and the level's directors before them) for the unknowns z."""
        u = self.unpack(z)
        return u["dr"].copy(), self.D - u["dD"], u["dR"].copy(), u["ds"].copy(), u["dX"].copy()

    # -- the stepper's state ---------------------------------------------------------------------------------------

    def step_state(self, st, model):
        """One step, returned as the stepper's :class:`varint.schemes.state.State`: q (the tube's free labels and radii, the
        rod's frames and positions), p (label momenta mbar X'.X_s, wall momenta a w R', node momenta m v + the
        labels' sum_k mbar_k N_j(s_k) X'_k, body angular momenta), lam (the liquid's pressures).  A state at another
        level is a resumed run, restored from its data (:meth:`state_data`)."""
        from ..terms.rod import pack_level
        from .state import State

        if st.n != self.n:
            if not st.data or "tem_r" not in st.data:
                raise SolverError("time.scheme: 'energy-momentum' cannot restart from this checkpoint (it lacks the "
                                  "step's own state: written by an older varint)")
            self.restore(st.data, st.n)
        self.step()
        t = self.t
        q, p, lam = st.q.copy(), st.p.copy(), st.lam.copy()
        cfg = np.concatenate([self.s, self.R] + ([self.mu_liq] if self.incompressible else []))
        ztube = t.B.T @ (cfg - t.c0)
        nq = len(t.q_init)
        q[model.tube_q] = ztube[:nq]
        lam[model.tube_lam] = ztube[nq:]
        from ..lattice.centreline import centreline_and_weights

        nodes, Nw, _, _, dX, _ = centreline_and_weights(self.s, self.r, self.ds)
        Xdot = np.concatenate([self.v[:1], self.Xdot, self.v[-1:]])
        mb = np.asarray(t.label_mass_all, dtype=float)
        rates = np.zeros(len(cfg))
        rates[: self.M + 1] = mb * np.sum(Xdot * dX, 1)
        rates[self.M + 1: self.M + 1 + len(self.R)] = self.aw * self.Rdot
        p[model.tube_p] = (t.B.T @ rates)[:nq]
        q[model.rod_q] = pack_level(self.D, self.r, self.origin)
        prod = self.m[:, None] * self.v
        inner = (mb[1:-1, None] * Nw[1:-1])[:, :, None] * self.Xdot[:, None, :]
        np.add.at(prod, nodes[1:-1].ravel(), inner.reshape(-1, 3))
        Pi = np.einsum("nji,nj->ni", self.D, np.cross(np.swapaxes(self.D, 1, 2),
                                                      np.swapaxes(self.E[:, None, :] * self.V, 1, 2)).sum(1))
        p[model.rod_p] = np.concatenate([prod.ravel(), Pi.ravel()])
        data = dict(st.data or {})
        data.update(self.state_data())
        return State(self.n, self.n * self.h, q, p, lam, st.v, st.q.copy(), data)

    #: the step's own state beyond (q, p), for checkpoints
    _STATE = ("r", "D", "v", "V", "lam", "mu_rod", "R", "Rdot", "s", "sdot", "X", "Xdot", "nu", "mu_liq")

    def state_data(self):
        data = {f"tem_{k}": np.asarray(getattr(self, k), dtype=float).ravel() for k in self._STATE}
        data["tem_origin"] = self.origin.copy()
        data["tem_work"] = np.array([self.work])
        if self.shock is not None:  # the heated entropies (a halved step goes back to the level's)
            data["tem_S"], data["tem_viscous_work"] = self.Sk.copy(), np.array([self.viscous_work])
        if self._prev is not None:
            for k, v in zip(("dr", "D", "dR", "ds", "dX"), self._prev):
                data[f"tem_prev_{k}"] = np.asarray(v, dtype=float).ravel()
        return data

    def restore(self, data, n):
        """Continue from :meth:`state_data` at level n; the kept factorisation is dropped."""
        for k in self._STATE:
            cur = getattr(self, k)
            setattr(self, k, np.array(data[f"tem_{k}"], dtype=float).reshape(np.shape(cur)))
        # a checkpoint written before the floating origin: its positions are absolute
        self.origin = np.array(data.get("tem_origin", np.zeros(3)), dtype=float).reshape(3)
        self.work = float(np.asarray(data.get("tem_work", [0.0])).ravel()[0])
        if self.shock is not None and "tem_S" in data:
            self.Sk[:] = np.asarray(data["tem_S"], dtype=float)
            self.viscous_work = float(np.asarray(data["tem_viscous_work"]).ravel()[0])
        self._prev = None
        if "tem_prev_dr" in data:
            shapes = (self.r.shape, self.D.shape, self.R.shape, (self.M - 1,), self.X.shape)
            self._prev = tuple(np.array(data[f"tem_prev_{k}"], dtype=float).reshape(sh)
                               for k, sh in zip(("dr", "D", "dR", "ds", "dX"), shapes))
        self.n = int(n)
        self._lu = None

    # -- monitors ----------------------------------------------------------------------------------------------------

    def kinetic_energy(self):
        return float(0.5 * np.sum(self.m * np.sum(self.v ** 2, 1)) + 0.5 * np.sum(self.E[:, None, :] * self.V ** 2)
                     + 0.5 * np.sum(self.aw * self.Rdot ** 2) + 0.5 * np.sum(self.mbar * np.sum(self.Xdot ** 2, 1)))

    def energy(self):
        """The conserved total energy: kinetic (constant metric) + U (rod, wall, fluid, p_ext, loads)."""
        return self.kinetic_energy() + self._potential_level()

    def _potential_level(self):
        """U at the current level, with the loads' work on the floating origin's moves (U's terms linear in r, X)."""
        loads = self.fext.sum(0) + self.mbar.sum() * self.g
        return float(self.potential(self.r, self.D, self.R, self.s, self.X)) - float(loads @ self.origin)

    def linear_momentum(self):
        return (self.m[:, None] * self.v).sum(0) + (self.mbar[:, None] * self.Xdot).sum(0)

    def angular_momentum(self):
        """About the fixed origin: the floating origin's o x P plus the moments about o."""
        return np.cross(self.origin, self.linear_momentum()) + self._angular_momentum_local()

    def _angular_momentum_local(self):
        return (np.cross(self.r, self.m[:, None] * self.v).sum(0)
                + np.cross(np.swapaxes(self.D, 1, 2), np.swapaxes(self.E[:, None, :] * self.V, 1, 2)).sum((0, 1))
                + np.cross(self.X, self.mbar[:, None] * self.Xdot).sum(0))

    def label_constraint_residual(self):
        W = label_weights(self.s[1:-1], self.N + 1, self.ds)
        return float(np.max(np.abs(self.X - W @ self.r))) if self.M > 1 else 0.0

    def monitors(self):
        """The stepper's monitors for the coupled tube (the names of ``Simulation._coupled_monitors``): the conserved
        energy and its parts, the momenta of rod and fluid, mass, entropy, the liquid's volume residual."""
        rod = self.rod
        mb = np.asarray(self.t.label_mass_all, dtype=float)
        Kr = 0.5 * float(np.sum(rod.node_mass * np.sum(self.v ** 2, 1)) + np.sum(self.E[:, None, :] * self.V ** 2))
        Kf = 0.5 * float(np.sum(self.mbar * np.sum(self.Xdot ** 2, 1)) + mb[0] * self.v[0] @ self.v[0]
                         + mb[-1] * self.v[-1] @ self.v[-1])
        Kw = 0.5 * float(np.sum(self.aw * self.Rdot ** 2))
        U = self._potential_level()
        P = self.linear_momentum()
        J_local = self._angular_momentum_local()
        mtot = self.m.sum() + self.mbar.sum()
        rc = ((self.m[:, None] * self.r).sum(0) + (self.mbar[:, None] * self.X).sum(0)) / mtot  # from the origin o
        out = {"energy": Kr + Kf + Kw + U, "kinetic_energy": Kr + Kf + Kw, "energy_rod_kinetic": Kr,
               "energy_fluid_kinetic": Kf, "energy_wall_kinetic": Kw, "energy_potential": U,
               "linear_momentum": P, "angular_momentum": np.cross(self.origin, P) + J_local,
               "angular_momentum_cm": J_local - np.cross(rc, P),
               "frame_orthogonality": float(np.max(np.abs(_T(self.D) @ self.D - np.eye(3)))),
               "label_constraint": self.label_constraint_residual(),
               "mass": float(np.sum(rod.node_mass) + np.sum(self.mk))}
        if self.has_torque:
            out["external_work"] = self.work  # the tip torque's, since t = 0: E - external_work is conserved
        if self.eos is not None and self.eos.has_entropy:
            out["entropy"] = float(np.sum(self.mk * self.Sk))
        if self.shock is not None:
            out["viscous_work"] = self.viscous_work
        if self.incompressible:
            V = self.volumes(self.s, self.R, self.r, self.D)
            out["constraint_residual"] = float(np.max(np.abs(V / self.V0 - 1.0)))
        return out
