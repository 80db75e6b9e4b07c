"""A compiled step of the rod-only model: the same discrete equations as :class:`varint.stepper.Step`, one numba call.

The stepper (varint/stepper.py ``Simulation._solve``) solves a rod step n -> n+1 in position-momentum form
(docs/theory.md §9, §4a; Marsden & West, Acta Numerica 2001, §3.2)

    R(z) = fold[ rot_n( pi_n + D1 L_d(q_n, q_{n+1}(z)) + f^-_n ) ]_mask = 0,    pi_{n+1} = fold[ D2 L_d + f^+_n ],

with the step unknowns z = (b, xi) on the support mask (r_{n+1} = r_n + Lambda_n b, Lambda_{n+1} = Lambda_n cay(xi)),
the translational rows rotated into the level-n body frames (rot_n) and a periodic rod's image node folded into
node 0.  Here the same residual is assembled by the same element kernel (``varint.rod._k_element``, the analytic
gradient of one element's L_d) and the same Newton blocks (``varint.rod._k_step_blocks``, complex step of that
gradient), but

* the whole Newton iteration runs in one compiled routine (``_k_step``) on preallocated buffers: no Python and no
  allocation per iteration;
* the Jacobian is stored as a band (node-ordered unknowns; a periodic rod's nodes interleaved 0, 1, N-1, 2, N-2, ...
  so that its wrap-around couplings stay in the band) and factorised by a compiled banded LU with partial pivoting
  (``_k_band_lu``, LAPACK's dgbtf2), reused across chord iterations and across steps, refreshed by the stepper's rule
  (contraction rate above ``RATE_REFRESH_ROD``);
* the predictor extrapolates the last two steps' (b, xi) linearly (second order; the stepper's is the last step's,
  first order), and the iteration stops, as the stepper's, at the round-off floor (``POLISH_ROD`` polishing updates
  past ``newton_tol`` while they still contract).

What it covers: a rod without ``[fluid]``/``[wall]`` and without ``rod.constraint`` (the shearable rod), 2D and 3D,
clamped / pinned / free / periodic ends, either measure, gravity, the dead tip force and the dead tip torque.
If the compiled chord iteration fails, :meth:`FastRodStep.step` falls back to the stepper's damped Newton on
:class:`varint.stepper.Step` (the same equations, the slow path).

Use::

    fast = FastRodStep(model, h, tol)
    state = fast.step(state)        # a varint.stepper.State, as Simulation.step produces
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .errors import SolverError
from .newton import newton_damped
from .rod import (EPS_CS, ORIGIN_GRID, POLISH_ROD, RATE_REFRESH_ROD, XI_MAX, _k_cay, _k_element, _k_step_blocks,
                  pack_level, unpack_level)

__all__ = ["FastRodStep", "supports"]

EPS = np.finfo(float).eps
#: the stepper's Newton constants (varint.newton): stagnation, round-off band and growth
STAGNATION_RATE = 0.5
ROUNDOFF_BAND = 100.0
MAX_ROUNDOFF_RATE = 10.0
CHORD_ITERATIONS = 30  #: iterations allowed on an inherited factorisation (Simulation._newton_options)


def supports(model):
    """Why the fast step cannot run ``model`` (one line), or None when it can."""
    if model.rod is None:
        return "no [rod]"
    if model.tube is not None:
        return "a [fluid] or [wall] on the rod (the coupled tube)"
    if model.rod.constrained:
        return "rod.constraint = 'inextensible_unshearable'"
    if model.scheme != "midpoint":
        return f"time.scheme = {model.scheme!r}"
    if any(type(f).__name__ != "TipTorque" for f in model.forces):
        return "a force other than the tip torque"
    return None


# ---------------------------------------------------------------------------------------------------------------
# compiled banded LU with partial pivoting (LAPACK dgbtf2 / dgbtrs), band stored by columns:
# A[i, j] = ab[j, kv + i - j], kv = kl + ku, ab of shape (n, 2 kl + ku + 1) (rows kv+1.. hold L, rows < ku fill-in)


@njit(cache=True)
def _k_band_lu(ab, kl, ku, ipiv):
    """In-place LU of a band matrix with partial pivoting; returns 0, or j + 1 if the pivot of column j is zero."""
    n = ab.shape[0]
    kv = kl + ku
    ju = 0
    for j in range(n):
        km = min(kl, n - 1 - j)
        jp = 0
        big = abs(ab[j, kv])
        for i in range(1, km + 1):
            a = abs(ab[j, kv + i])
            if a > big:
                big = a
                jp = i
        ipiv[j] = j + jp
        if ab[j, kv + jp] == 0.0:
            return j + 1
        ju = max(ju, min(j + ku + jp, n - 1))
        if jp != 0:
            for c in range(j, ju + 1):
                a = ab[c, kv + j - c]
                ab[c, kv + j - c] = ab[c, kv + j + jp - c]
                ab[c, kv + j + jp - c] = a
        if km > 0:
            inv = 1.0 / ab[j, kv]
            for i in range(1, km + 1):
                ab[j, kv + i] *= inv
            for c in range(j + 1, ju + 1):
                a = ab[c, kv + j - c]
                if a != 0.0:
                    for i in range(1, km + 1):
                        ab[c, kv + j + i - c] -= ab[j, kv + i] * a
    return 0


@njit(cache=True)
def _k_band_solve(ab, kl, ku, ipiv, b):
    """Solve A x = b in place with the factors of :func:`_k_band_lu`."""
    n = ab.shape[0]
    kv = kl + ku
    for j in range(n - 1):
        km = min(kl, n - 1 - j)
        p = ipiv[j]
        if p != j:
            t = b[p]
            b[p] = b[j]
            b[j] = t
        bj = b[j]
        if bj != 0.0:
            for i in range(1, km + 1):
                b[j + i] -= ab[j, kv + i] * bj
    for j in range(n - 1, -1, -1):
        b[j] /= ab[j, kv]
        bj = b[j]
        if bj != 0.0:
            for i in range(max(0, j - kv), j):
                b[i] -= ab[j, kv + i - j] * bj


# ---------------------------------------------------------------------------------------------------------------
# the step's pieces


@njit(cache=True)
def _k_chart(Lam_n, r_n, z, idx, periodic, xi, r_1):
    """(xi, r_1) of the step unknowns z: u = 0 off the mask, r_1 = r_n + Lambda_n b (Step.point)."""
    n1 = Lam_n.shape[0]
    for j in range(n1):
        jj = 0 if (periodic and j == n1 - 1) else j  # a periodic rod's image node moves with node 0
        b0 = z[idx[jj, 0]] if idx[jj, 0] >= 0 else 0.0
        b1 = z[idx[jj, 1]] if idx[jj, 1] >= 0 else 0.0
        b2 = z[idx[jj, 2]] if idx[jj, 2] >= 0 else 0.0
        for i in range(3):
            r_1[j, i] = r_n[j, i] + Lam_n[j, i, 0] * b0 + Lam_n[j, i, 1] * b1 + Lam_n[j, i, 2] * b2
            k = idx[jj, 3 + i]
            xi[j, i] = z[k] if k >= 0 else 0.0


@njit(cache=True)
def _k_levels_gradient(h, ds, rhoA, inertia, Jd, Kd, g, force, paper, Lam_n, r_n, xi, r_1, lev, D, M, V, e1, e2):
    """D = D1 (lev 0) or D2 (lev 1) of L_d: the element gradients summed, and the tip force's node piece
    (varint.rod._k_gradient with preallocated scratch).  Returns False if a Cayley chart is singular."""
    N = Lam_n.shape[0] - 1
    for j in range(N + 1):
        for i in range(6):
            D[j, i] = 0.0
    for e in range(N):
        # _k_cay / _k_cay_inv divide by 4 + |w|^2 and 1 + tr: a pi rotation raises ZeroDivisionError in numba
        _k_element(h, ds, rhoA, inertia, Jd, Kd, g, paper, Lam_n[e], Lam_n[e + 1], r_n[e], r_n[e + 1],
                   xi[e], xi[e + 1], r_1[e], r_1[e + 1], lev, lev + 1, e1, e2, M, V)
        src = e1 if lev == 0 else e2
        for i in range(6):
            D[e, i] += src[i]
            D[e + 1, i] += src[6 + i]
    for i in range(3):
        D[N, i] += 0.5 * h * force[i]
    return True


@njit(cache=True)
def _k_residual(h, ds, rhoA, inertia, Jd, Kd, g, force, torque, paper, periodic, Lam_n, r_n, pin, z, idx, bpos,
                xi, r_1, D, M, V, e1, e2, out):
    """The step residual (Step.residual) at z, written into out in band order (out[bpos[k]] = R_k).
    Returns False when it is not finite."""
    N = Lam_n.shape[0] - 1
    _k_chart(Lam_n, r_n, z, idx, periodic, xi, r_1)
    _k_levels_gradient(h, ds, rhoA, inertia, Jd, Kd, g, force, paper, Lam_n, r_n, xi, r_1, 0, D, M, V, e1, e2)
    for j in range(N + 1):
        for i in range(6):
            D[j, i] += pin[j, i]
    # f^- of the dead tip torque: (h/2) Lambda_N^n T T in the tip's body frame (varint.forces.TipTorque)
    for i in range(3):
        D[N, 3 + i] += 0.5 * h * (Lam_n[N, 0, i] * torque[0] + Lam_n[N, 1, i] * torque[1] + Lam_n[N, 2, i] * torque[2])
    # the translational rows in the level-n body frames
    for j in range(N + 1):
        a0 = Lam_n[j, 0, 0] * D[j, 0] + Lam_n[j, 1, 0] * D[j, 1] + Lam_n[j, 2, 0] * D[j, 2]
        a1 = Lam_n[j, 0, 1] * D[j, 0] + Lam_n[j, 1, 1] * D[j, 1] + Lam_n[j, 2, 1] * D[j, 2]
        a2 = Lam_n[j, 0, 2] * D[j, 0] + Lam_n[j, 1, 2] * D[j, 1] + Lam_n[j, 2, 2] * D[j, 2]
        D[j, 0] = a0
        D[j, 1] = a1
        D[j, 2] = a2
    if periodic:
        for i in range(6):
            D[0, i] += D[N, i]
            D[N, i] = 0.0
    ok = True
    for j in range(N + 1):
        for i in range(6):
            k = idx[j, i]
            if k >= 0 and not (periodic and j == N):
                out[bpos[k]] = D[j, i]
                if not np.isfinite(D[j, i]):
                    ok = False
    return ok


@njit(cache=True)
def _k_band_jacobian(h, ds, rhoA, inertia, Jd, Kd, g, paper, Lam_n, r_n, xi, r_1, cmask, idx, bpos, kl, ku, blocks, ab):
    """The step's exact Jacobian (Step.jacobian: element blocks of varint.rod._k_step_blocks) assembled into
    band storage ab (LAPACK layout by columns, see _k_band_lu) in band order.  Returns False if not finite."""
    N = Lam_n.shape[0] - 1
    _k_step_blocks(h, ds, rhoA, inertia, Jd, Kd, g, paper, Lam_n, r_n, xi, r_1, cmask, EPS_CS, blocks)
    kv = kl + ku
    ab[:, :] = 0.0
    ok = True
    for e in range(N):
        for a in range(12):
            ka = idx[e + a // 6, a % 6]
            if ka < 0:
                continue
            pa = bpos[ka]
            for c in range(12):
                kc = idx[e + c // 6, c % 6]
                if kc < 0:
                    continue
                v = blocks[e, a, c]
                if not np.isfinite(v):
                    ok = False
                ab[bpos[kc], kv + pa - bpos[kc]] += v
    return ok


@njit(cache=True)
def _k_floor_ok(dz, z, scale):
    """Every update within ROUNDOFF_BAND of its kind's round-off floor (varint.newton._within_floor; the rod's
    kinds are the two scales, ds for b and 1 for xi; its unknowns are no displacements of a lattice: offset 0)."""
    s_t = 0.0
    s_r = 0.0
    for k in range(z.shape[0]):
        v = abs(z[k]) / scale[k]
        if scale[k] == 1.0:
            s_r = max(s_r, v)
        else:
            s_t = max(s_t, v)
    for k in range(z.shape[0]):
        size = s_r if scale[k] == 1.0 else s_t
        if abs(dz[k]) / scale[k] > ROUNDOFF_BAND * EPS * size:
            return False
    return True


@njit(cache=True, inline="always")
def _k_stats(stats, converged, iterations, n_res, n_jac, err, factor_valid, code):
    stats[0] = converged
    stats[1] = iterations
    stats[2] = n_res
    stats[3] = n_jac
    stats[4] = err
    stats[5] = factor_valid
    stats[6] = code


@njit(cache=True)
def _k_step(h, ds, rhoA, inertia, Jd, Kd, g, force, torque, paper, periodic, Lam_n, r_n, pin, idx, cmask, bpos, kl, ku,
            scale, tol, max_iter, rate_refresh, polish, z, dz, rb, xi, r_1, D, M, V, e1, e2, blocks, ab, ipiv, have_factor,
            stats):
    """Newton's chord iteration of varint.newton.newton on the step residual, all compiled.

    ``z`` holds the predictor on entry and the solution on exit; ``ab``/``ipiv`` the factorisation, reused when
    ``have_factor``.  ``stats`` receives (converged, iterations, residuals, jacobians, error, factor valid, code):
    code 0 converged, 1 not finite, 2 diverging, 3 no convergence, 4 singular."""
    n = z.shape[0]
    n_res = 0
    n_jac = 0
    jac_iter = -1  # -1: inherited factorisation
    if not have_factor:
        _k_chart(Lam_n, r_n, z, idx, periodic, xi, r_1)
        ok = _k_band_jacobian(h, ds, rhoA, inertia, Jd, Kd, g, paper, Lam_n, r_n, xi, r_1, cmask, idx, bpos, kl, ku,
                              blocks, ab)
        n_jac += 1
        jac_iter = 0
        if not ok or _k_band_lu(ab, kl, ku, ipiv) != 0:
            _k_stats(stats, 0, 0, n_res, n_jac, np.inf, 0, 4)
            return
    err_prev = -1.0
    rate = np.nan
    rate_prev = np.nan
    it = 0
    err = np.inf
    n_growing = 0
    polished = 0
    while it < max_iter + polished:
        ok = _k_residual(h, ds, rhoA, inertia, Jd, Kd, g, force, torque, paper, periodic, Lam_n, r_n, pin, z, idx, bpos,
                         xi, r_1, D, M, V, e1, e2, rb)
        n_res += 1
        if not ok:
            _k_stats(stats, 0, it, n_res, n_jac, np.inf, 1, 1)
            return
        _k_band_solve(ab, kl, ku, ipiv, rb)
        err = 0.0
        zmax = 0.0
        for k in range(n):
            d = -rb[bpos[k]]
            dz[k] = d
            z[k] += d
            err = max(err, abs(d) / scale[k])
            zmax = max(zmax, abs(z[k]) / scale[k])
        it += 1
        floor = 8.0 * EPS * zmax
        if err <= tol or err <= floor:
            contracting = polished == 0 or err < 0.7 * err_prev
            if polished < polish and err > floor and contracting:
                polished += 1
                err_prev = err
                continue
            _k_stats(stats, 1, it, n_res, n_jac, err, 1, 0)
            return
        if polished > 0:  # a polishing update that grew past tol: round-off, keep the converged point
            for k in range(n):
                z[k] -= dz[k]
            _k_stats(stats, 1, it, n_res, n_jac, err_prev, 1, 0)
            return
        if err_prev >= 0.0:
            rate = err / err_prev
            slow_inherited = jac_iter < 0 and it >= CHORD_ITERATIONS
            if not np.isfinite(rate) or rate > rate_refresh or slow_inherited:
                recent = jac_iter >= 0 and jac_iter >= it - 2
                if recent and err <= 100.0 * tol:
                    _k_stats(stats, 1, it, n_res, n_jac, err, 1, 0)  # stagnated at round-off
                    return
                if STAGNATION_RATE <= rate < MAX_ROUNDOFF_RATE and rate_prev <= rate_refresh and _k_floor_ok(dz, z, scale):
                    _k_stats(stats, 1, it, n_res, n_jac, err, 1, 0)  # stopped at the round-off floor
                    return
                growing = (not np.isfinite(rate)) or rate >= 1.0
                n_growing = n_growing + 1 if growing else 0
                if n_growing >= 3:
                    _k_stats(stats, 0, it, n_res, n_jac, err, 1, 2)
                    return
                if jac_iter < it:
                    _k_chart(Lam_n, r_n, z, idx, periodic, xi, r_1)
                    ok = _k_band_jacobian(h, ds, rhoA, inertia, Jd, Kd, g, paper, Lam_n, r_n, xi, r_1, cmask, idx, bpos,
                                          kl, ku, blocks, ab)
                    n_jac += 1
                    jac_iter = it
                    err_prev = -1.0
                    rate_prev = np.nan
                    if not ok or _k_band_lu(ab, kl, ku, ipiv) != 0:
                        _k_stats(stats, 0, it, n_res, n_jac, err, 0, 4)
                        return
                    continue
            rate_prev = rate
        err_prev = err
    _k_stats(stats, 0, it, n_res, n_jac, err, 1, 3)


@njit(cache=True)
def _k_finish(h, ds, rhoA, inertia, Jd, Kd, g, force, torque, paper, periodic, floating, period, Lam_n, r_n, origin, z, idx,
              xi, r_1, D, M, V, e1, e2, C, q1, p1, v1, turn):
    """The accepted step's new level: q_{n+1} (Step.retract: frames re-orthonormalised by one polar Newton step, a
    periodic image node, the floating origin on its binary grid), pi_{n+1} = fold(D2 L_d + f^+) (Step.momentum_plus)
    and the predictor's data v = (Lambda_n^T (r_1 - r_n), xi) (Simulation._step_velocity).  turn[0:2] = the largest
    |xi| and its node."""
    N = Lam_n.shape[0] - 1
    n1 = N + 1
    _k_chart(Lam_n, r_n, z, idx, periodic, xi, r_1)
    turn[0] = 0.0
    turn[1] = 0.0
    for j in range(n1):
        t = math.sqrt(xi[j, 0] ** 2 + xi[j, 1] ** 2 + xi[j, 2] ** 2)
        if t > turn[0]:
            turn[0] = t
            turn[1] = j
    _k_levels_gradient(h, ds, rhoA, inertia, Jd, Kd, g, force, paper, Lam_n, r_n, xi, r_1, 1, D, M, V, e1, e2)
    # the new frames: Lambda_n cay(xi), then one polar Newton step L (3 I - L^T L) / 2 (varint.rod.reorthonormalize)
    L1 = q1[3 * n1:12 * n1].reshape(n1, 3, 3)
    T = M[4]  # (element scratch, free here)
    for j in range(n1):
        _k_cay(xi[j, 0], xi[j, 1], xi[j, 2], C)
        for a in range(3):
            for b in range(3):
                T[a, b] = Lam_n[j, a, 0] * C[0, b] + Lam_n[j, a, 1] * C[1, b] + Lam_n[j, a, 2] * C[2, b]
        for a in range(3):
            for b in range(3):
                s = 3.0 if a == b else 0.0
                s -= T[0, a] * T[0, b] + T[1, a] * T[1, b] + T[2, a] * T[2, b]
                C[a, b] = s
        for a in range(3):
            for b in range(3):
                L1[j, a, b] = 0.5 * (T[a, 0] * C[0, b] + T[a, 1] * C[1, b] + T[a, 2] * C[2, b])
    # f^+ of the tip torque with the new (re-orthonormalised) tip frame
    for i in range(3):
        D[N, 3 + i] += 0.5 * h * (L1[N, 0, i] * torque[0] + L1[N, 1, i] * torque[1] + L1[N, 2, i] * torque[2])
    if periodic:
        for i in range(6):
            D[0, i] += D[N, i]
            D[N, i] = 0.0
    for j in range(n1):
        for i in range(3):
            p1[3 * j + i] = D[j, i]
            p1[3 * n1 + 3 * j + i] = D[j, 3 + i]
    # the predictor's data, from the point's r_1 (before the image node and the origin's shift)
    for j in range(n1):
        for i in range(3):
            v1[3 * j + i] = (Lam_n[j, 0, i] * (r_1[j, 0] - r_n[j, 0]) + Lam_n[j, 1, i] * (r_1[j, 1] - r_n[j, 1])
                             + Lam_n[j, 2, i] * (r_1[j, 2] - r_n[j, 2]))
            v1[3 * n1 + 3 * j + i] = xi[j, i]
    if periodic:
        for a in range(3):
            r_1[N, a] = r_1[0, a] + period[a]
            for b in range(3):
                L1[N, a, b] = L1[0, a, b]
    for i in range(3):
        shift = np.round(r_1[0, i] / ORIGIN_GRID) * ORIGIN_GRID if floating else 0.0
        for j in range(n1):
            q1[3 * j + i] = r_1[j, i] - shift
        q1[12 * n1 + i] = origin[i] + shift


class FastRodStep:
    """The compiled rod step (module docstring): ``step(state) -> new State``, the stepper's equations.

    ``tol``, ``max_iter``: Newton's (default: the scene's ``time.newton_tol`` and ``max(time.max_iterations,
    40)``, as :class:`varint.stepper.Simulation`); ``predictor``: "linear" (the last two steps' (b, xi)
    extrapolated, default) or "constant" (the last step's, the stepper's).
    """

    def __init__(self, model, h=None, tol=None, max_iter=None, predictor="linear"):
        why = supports(model)
        if why is not None:
            raise SolverError(f"rod step: the fast path does not run this model ({why})")
        rod = model.rod
        tcfg = model.scene.time
        self.model, self.rod = model, rod
        self.h = float(h if h is not None else tcfg.step)
        self.tol = float(tol if tol is not None else tcfg.newton_tol)
        self.max_iter = int(max(max_iter if max_iter is not None else tcfg.max_iterations, 40))
        if predictor not in ("linear", "constant"):
            raise ValueError(f"predictor: {predictor!r} is not 'linear' or 'constant'")
        self.predictor = predictor
        self.floating = bool(rod.free)  # Simulation.floating_origin
        N = rod.N
        n1 = N + 1
        _, rhoA, inertia, J, K, g, force = rod._consts()
        torque = np.zeros(3)
        for f in model.forces:
            torque = torque + f.torque
        self.consts = (self.h, rod.ds, float(rhoA), inertia, J, K, np.ascontiguousarray(g, dtype=float),
                       np.ascontiguousarray(force, dtype=float), torque, bool(rod.paper_measure), bool(rod.periodic))
        self.period = np.ascontiguousarray(rod.period, dtype=float)
        self.idx = np.ascontiguousarray(rod.node_index(), dtype=np.int64)
        self.cmask = np.ascontiguousarray(rod.column_mask)
        nz = rod.nz
        self.nz = nz
        # band order: node-major (z's own order) for open ends; a periodic rod's nodes interleaved so that the
        # wrap-around element (N-1, N = image of 0) stays within a few nodes of the diagonal
        if rod.periodic:
            order = [0]
            lo, hi = 1, N - 1
            while lo <= hi:
                order.append(lo)
                if hi != lo:
                    order.append(hi)
                lo, hi = lo + 1, hi - 1
            node_pos = np.empty(N, np.int64)
            node_pos[np.array(order)] = np.arange(N)
            per_node = int(rod.mask[0].sum())
            k_node = np.repeat(np.arange(N), per_node)
            k_dir = np.tile(np.arange(per_node), N)
            self.bpos = np.ascontiguousarray(node_pos[k_node] * per_node + k_dir, dtype=np.int64)
        else:
            self.bpos = np.arange(nz, dtype=np.int64)
        rows, cols, _ = rod._block_pattern()
        d = self.bpos[rows] - self.bpos[cols]
        self.kl, self.ku = int(max(d.max(), 0)), int(max(-d.min(), 0))
        sc = np.ones((n1, 6))
        sc[:, :3] = rod.ds
        self.scale = np.ascontiguousarray(sc[rod.mask])  # Simulation._scales
        # preallocated buffers (reused by every step and every iteration)
        self.z = np.zeros(nz)
        self.dz = np.zeros(nz)
        self.rb = np.zeros(nz)
        self.xi = np.zeros((n1, 3))
        self.r_1 = np.zeros((n1, 3))
        self.D = np.zeros((n1, 6))
        self.M = np.zeros((5, 3, 3))
        self.V = np.zeros((16, 3))
        self.e1 = np.zeros(12)
        self.e2 = np.zeros(12)
        self.C = np.zeros((3, 3))
        self.blocks = np.zeros((N, 12, 12))
        self.ab = np.zeros((nz, 2 * self.kl + self.ku + 1))
        self.ipiv = np.zeros(nz, np.int64)
        self.pin = np.zeros((n1, 6))
        self.turn = np.zeros(2)
        self.stats = np.zeros(7)
        self.have_factor = False
        self._prev = None  # (n, v) of the step before the state's last one, for the linear predictor
        self._step = None  # varint.stepper.Step for the fallback, built on first need
        self.fallbacks = 0
        self.last = {"iterations": 0, "n_residual": 0, "n_jacobian": 0}

    # -- the pieces, for tests ----------------------------------------------------------------------------------

    def _level(self, q, p):
        rod = self.rod
        n1 = rod.N + 1
        Lam, r, origin = unpack_level(q[self.model.rod_q], rod.N)
        pp = p[self.model.rod_p]
        self.pin[:, :3] = pp[:3 * n1].reshape(n1, 3)
        self.pin[:, 3:] = pp[3 * n1:].reshape(n1, 3)
        return np.ascontiguousarray(Lam), np.ascontiguousarray(r), np.array(origin)

    def residual(self, q0, p0, z):
        """The compiled step residual at z (Step.residual's order)."""
        Lam, r, _ = self._level(q0, p0)
        out = np.zeros(self.nz)
        _k_residual(*self.consts[:9], self.consts[9], self.consts[10], Lam, r, self.pin, np.ascontiguousarray(z, dtype=float),
                    self.idx, self.bpos, self.xi, self.r_1, self.D, self.M, self.V, self.e1, self.e2, out)
        return out[self.bpos]

    def jacobian(self, q0, z):
        """The compiled band Jacobian at z as a dense (nz, nz) array in z's order (Step.jacobian's)."""
        Lam, r, _ = self._level(q0, np.zeros(len(q0)))
        z = np.ascontiguousarray(z, dtype=float)
        h, ds, rhoA, inertia, J, K, g, force, torque, paper, periodic = self.consts
        _k_chart(Lam, r, z, self.idx, periodic, self.xi, self.r_1)
        ab = np.zeros_like(self.ab)
        _k_band_jacobian(h, ds, rhoA, inertia, J, K, g, paper, Lam, r, self.xi, self.r_1, self.cmask, self.idx, self.bpos,
                         self.kl, self.ku, self.blocks, ab)
        kv = self.kl + self.ku
        A = np.zeros((self.nz, self.nz))
        for jb in range(self.nz):
            for ib in range(max(0, jb - self.ku), min(self.nz, jb + self.kl + 1)):
                A[ib, jb] = ab[jb, kv + ib - jb]
        return A[np.ix_(self.bpos, self.bpos)]

    # -- the step -------------------------------------------------------------------------------------------------

    def predict(self, state):
        """z0: the last step's (b, xi) on the mask, or (linear) 2 v_n - v_{n-1} when the step before is known."""
        rod = self.rod
        n1 = rod.N + 1
        v = state.v[self.model.rod_p]
        if self.predictor == "linear" and self._prev is not None and self._prev[0] == state.n - 1:
            v = 2.0 * v - self._prev[1]
        g = v.reshape(2, n1, 3)
        return np.concatenate([g[0], g[1]], axis=1)[rod.mask]

    def invalidate(self):
        """Forget the reused factorisation and the predictor's history (Simulation.invalidate_jacobian)."""
        self.have_factor = False
        self._prev = None

    def _fallback(self, state, z0):
        """The stepper's damped Newton on varint.stepper.Step (the same equations), from z0 and from rest."""
        from .stepper import Step

        if self._step is None:
            self._step = Step(self.model, self.h)
        sch = self._step
        F = lambda z: sch.residual(state.q, state.p, z)  # noqa: E731
        Jf = lambda z: sch.jacobian(state.q, z)  # noqa: E731
        self.fallbacks += 1
        res = newton_damped(F, Jf, z0, self.scale, self.tol, 4 * self.max_iter)
        if not res.converged:
            res = newton_damped(F, Jf, np.zeros(self.nz), self.scale, self.tol, 4 * self.max_iter)
        self.have_factor = False
        return res

    def step(self, state):
        """The next level: a :class:`varint.stepper.State` as Simulation.step makes it (rod-only model)."""
        from .stepper import State

        m, rod = self.model, self.rod
        n1 = rod.N + 1
        n_new = state.n + 1
        Lam, r, origin = self._level(state.q, state.p)
        z = self.z
        z[:] = self.predict(state)
        h, ds, rhoA, inertia, J, K, g, force, torque, paper, periodic = self.consts
        st = self.stats
        z0 = np.array(z)
        try:
            _k_step(h, ds, rhoA, inertia, J, K, g, force, torque, paper, periodic, Lam, r, self.pin, self.idx, self.cmask,
                    self.bpos, self.kl, self.ku, self.scale, self.tol, self.max_iter, RATE_REFRESH_ROD, POLISH_ROD, z,
                    self.dz, self.rb, self.xi, self.r_1, self.D, self.M, self.V, self.e1, self.e2, self.blocks, self.ab,
                    self.ipiv, self.have_factor, st)
        except ZeroDivisionError:  # an iterate turned a frame by pi: the Cayley chart is singular there
            st[:] = (0, 0, 0, 0, np.inf, 0, 1)
        self.have_factor = bool(st[5])
        iters, nres, njac = int(st[1]), int(st[2]), int(st[3])
        if not st[0]:
            res = self._fallback(state, z0)
            iters, nres, njac = iters + res.iterations, nres + res.n_residual, njac + res.n_jacobian
            if not res.converged:
                where = f"step {n_new} (t = {n_new * self.h:.6g} s)"
                raise SolverError(f"Newton failed at {where}: {res.message}; scaled update {res.error:.3g} after "
                                  f"{iters} iterations; try a smaller time.step", step=n_new, time=n_new * self.h,
                                  residual=res.error, rate=res.rate)
            z[:] = res.z
        q1 = np.empty(12 * n1 + 3)
        p1 = np.empty(6 * n1)
        v1 = np.empty(6 * n1)
        _k_finish(h, ds, rhoA, inertia, J, K, g, force, torque, paper, periodic, self.floating, self.period, Lam, r, origin,
                  z, self.idx, self.xi, self.r_1, self.D, self.M, self.V, self.e1, self.e2, self.C, q1, p1, v1, self.turn)
        if self.turn[0] > XI_MAX:
            j = int(self.turn[1])
            deg = math.degrees(2.0 * math.atan(0.5 * self.turn[0]))
            self.have_factor = False
            raise SolverError(f"step {n_new} (t = {n_new * self.h:.6g} s): node {j} turns by {deg:.0f} degrees in one "
                              "step (more than 90); reduce time.step", step=n_new, time=n_new * self.h)
        self._prev = (state.n, state.v[m.rod_p].copy())
        self.last = {"iterations": iters, "n_residual": nres, "n_jacobian": njac}
        return State(n_new, n_new * self.h, q1, p1, np.zeros(0), v1, state.q.copy(), m.state_data())
