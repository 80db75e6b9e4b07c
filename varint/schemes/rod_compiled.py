"""A compiled step of the rod-only model: the same discrete equations as :class:`varint.schemes.midpoint.Step`, one numba call.

The stepper (varint/run/simulation.py ``Simulation._solve``) solves a rod step n -> n+1 in position-momentum form
(docs/theory.md §9, §4a; Marsden & West, Acta Numerica 2001, §3.2)

    R(z) = fold[ rot_n( pi_n + D1 L_d(q_n, q_{n+1}(z)) + f^-_n ) ]_mask = 0,    pi_{n+1} = fold[ D2 L_d + f^+_n ],

with the step unknowns z = (b, xi) on the support mask (r_{n+1} = r_n + Lambda_n b, Lambda_{n+1} = Lambda_n cay(xi)),
the translational rows rotated into the level-n body frames (rot_n) and a periodic rod's image node folded into
node 0.  Here the same residual is assembled by the same element kernel (``varint.terms.rod.k_element``, the analytic
gradient of one element's L_d) and the same Newton blocks (``varint.terms.rod._k_step_blocks``, complex step of that
gradient), but

* the whole Newton iteration runs in one compiled routine (``_k_step``) on preallocated buffers: no Python and no
  allocation per iteration;
* the Jacobian is stored as a band (node-ordered unknowns; a periodic rod's nodes interleaved 0, 1, N-1, 2, N-2, ...
  so that its wrap-around couplings stay in the band) and factorised by a compiled banded LU with partial pivoting
  (``_k_band_lu``, LAPACK's dgbtf2), reused across chord iterations and across steps; the Jacobian is made by coloured
  forward differences of the compiled residual (``_k_band_jacobian_fd``, 3 d residuals instead of ~40 of complex
  steps), refreshed within a step by the stepper's rule (contraction rate above ``RATE_REFRESH_FAST``) and between
  steps once the iterations spent beyond the fewest on the current factorisation add up to the refresh's own cost
  (docs/theory.md §9, "Jacobian refresh");
* the predictor is the stepper's, the last step's (b, xi) (a linear extrapolation of the last two is an option and
  did not reduce the iterations: docs/theory.md §9, "Predictor"), and the iteration stops, as the stepper's, at the
  round-off floor (``POLISH_ROD`` polishing updates
  past ``newton_tol`` while they still contract);
* the momenta are kept to their own round-off (docs/theory.md §9, "Momenta to round-off"): each element is evaluated
  in coordinates centred on its node a at level n, with the velocities from the increments Lambda_n b rather than
  from differences of rounded positions (``varint.terms.rod.k_rod_gradient``), and after Newton a free rod's solution is corrected
  in the six rigid directions so that the step's momentum balances, in closed form, vanish (``_k_rigid_polish``).

What it covers: a rod without ``[fluid]``/``[wall]`` and without ``rod.constraint`` (the shearable rod), 2D and 3D,
clamped / pinned / free / periodic ends, either measure, gravity, the dead tip force and the dead tip torque.
If the compiled chord iteration fails, :meth:`FastRodStep.step` falls back to the stepper's damped Newton on
:class:`varint.schemes.midpoint.Step` (the same equations, the slow path).

Use::

    fast = FastRodStep(model, h, tol)
    state = fast.step(state)        # a varint.schemes.state.State, as Simulation.step produces

Compilation: the first step compiles for ~29 s (the tumbling rod, a quiet 2-core machine), then the kernels load from
numba's cache in 0.2 s.  They call varint.terms.rod's element kernels (k_element, k_rod_gradient, k_step_block: compiled
once and called, not inlined into each kernel here, which cost 41 s of compilation for the same speed), and numba's
cache is keyed on *this* file's timestamp only: after editing ``k_element`` (or the helpers it inlines) in
varint/terms/rod.py, touch this file (or clear its ``__pycache__`` entries), or a stale compiled copy keeps running.  tests/test_rod_step_fast.py, which
compares the residual and Jacobian with Step's, would catch it.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..errors import SolverError
from .limits import chart_limit_error
from .newton import newton_damped
from ..lattice.lie import k_cay
from ..terms.forces import k_tip_torque
from ..terms.rod import EPS_CS, ORIGIN_GRID, POLISH_ROD, XI_MAX, k_measure, k_rod_gradient, k_step_block, unpack_level

__all__ = ["FastRodStep", "supports"]

EPS = np.finfo(float).eps
#: the stepper's Newton constants (varint.schemes.newton): stagnation, round-off band and growth
STAGNATION_RATE = 0.5
ROUNDOFF_BAND = 100.0
MAX_ROUNDOFF_RATE = 10.0
CHORD_ITERATIONS = 30  #: iterations allowed on an inherited factorisation (Simulation._newton_options)
#: refresh the Jacobian when a chord iteration contracts by less than this.  The stepper's is 0.15
#: (``RATE_REFRESH_ROD``: its Jacobian costs 7-15 of its residuals); here a compiled residual costs ~12 us and a
#: compiled Jacobian ~550 us at 100 planar elements (~40 residuals, the complex steps), so fewer refreshes pay:
#: measured on the released cantilever at 100 elements, 0.15 / 0.3 / 0.5 gave 594 / 506 / 430 us per step at 16
#: steps per period (0.43 / 0.25 / 0.18 Jacobians per step) and 298 / 267 / 269 at 64 (shared machine)
RATE_REFRESH_FAST = 0.5
#: the difference step of the coloured finite-difference Jacobian (``_k_band_jacobian_fd``), times each unknown's
#: scale (ds for b, 1 for xi): its chord contraction equals the exact Jacobian's to 3 digits at 1e-5..1e-8 (100 planar
#: elements, docs/theory.md §9 "Jacobian refresh")
FD_STEP = 1e-7
#: a compiled band LU and band solve in residuals (per node direction count d = 3 planar, 6 in 3D), for the refresh's
#: cost in iterations (FastRodStep.refresh_cost); measured at 100 and 1000 elements (loaded 2-core machine): planar LU
#: ~1.2 residuals, solve ~0.4; 3D LU ~4.9, solve ~1.6
LU_SOLVE_COST = {3: (1.2, 0.4), 6: (4.9, 1.6)}


def supports(model):
    """Why the fast step cannot run ``model`` (one line), or None when it can."""
    if model.rod is None:
        return "no [rod]"
    if model.tube is not None:
        return "a [fluid] or [wall] on the rod (the coupled tube)"
    if model.rod.constrained:
        return "rod.constraint = 'inextensible_unshearable'"
    if any(type(f).__name__ != "TipTorque" for f in model.forces):
        return "a force other than the tip torque"
    return None


# ---------------------------------------------------------------------------------------------------------------
# compiled banded LU with partial pivoting (LAPACK dgbtf2 / dgbtrs), band stored by columns:
# A[i, j] = ab[j, kv + i - j], kv = kl + ku, ab of shape (n, 2 kl + ku + 1) (rows kv+1.. hold L, rows < ku fill-in)


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
def _k_chart(Lam_n, r_n, z, idx, periodic, xi, r_1, dr):
    """(xi, r_1, dr) of the step unknowns z: u = 0 off the mask, dr = Lambda_n b, r_1 = r_n + dr (Step.point).  The
    increments dr are kept: the kinetic terms take the velocities from them, not from the difference r_1 - r_n of
    rounded positions (docs/theory.md §9, "Momenta to round-off")."""
    n1 = Lam_n.shape[0]
    for j in range(n1):
        jj = 0 if (periodic and j == n1 - 1) else j  # a periodic rod's image node moves with node 0
        b0 = z[idx[jj, 0]] if idx[jj, 0] >= 0 else 0.0
        b1 = z[idx[jj, 1]] if idx[jj, 1] >= 0 else 0.0
        b2 = z[idx[jj, 2]] if idx[jj, 2] >= 0 else 0.0
        for i in range(3):
            dr[j, i] = Lam_n[j, i, 0] * b0 + Lam_n[j, i, 1] * b1 + Lam_n[j, i, 2] * b2
            r_1[j, i] = r_n[j, i] + dr[j, i]
            k = idx[jj, 3 + i]
            xi[j, i] = z[k] if k >= 0 else 0.0


@njit(cache=True, error_model="numpy")
def _k_residual(h, ds, rhoA, inertia, Jd, Kd, g, force, torque, paper, periodic, Lam_n, r_n, pin, z, idx, bpos,
                xi, r_1, dr, D, M, V, e1, e2, out):
    """The step residual (Step.residual) at z, written into out in band order (out[bpos[k]] = R_k).
    Returns False when it is not finite."""
    N = Lam_n.shape[0] - 1
    _k_chart(Lam_n, r_n, z, idx, periodic, xi, r_1, dr)
    k_rod_gradient(h, ds, rhoA, inertia, Jd, Kd, g, force, paper, Lam_n, r_n, xi, dr, 0, 1, D, D, M, V, e1, e2, False)
    for j in range(N + 1):
        for i in range(6):
            D[j, i] += pin[j, i]
    # f^- of the dead tip torque: (h/2) Lambda_N^n T T in the tip's body frame (varint.terms.forces.TipTorque)
    k_tip_torque(0.5 * h, Lam_n[N], torque, D[N, 3:])
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


@njit(cache=True, error_model="numpy")
def _k_band_jacobian(h, ds, rhoA, inertia, Jd, Kd, g, paper, Lam_n, r_n, xi, r_1, cmask, idx, bpos, kl, ku, cs, col, ab):
    """The step's exact Jacobian (Step.jacobian) in band storage ab (LAPACK layout by columns, see _k_band_lu), band
    order: each element's block (``varint.terms.rod.k_step_block``: the complex step of the analytic element gradient
    in the chart u = (b_a, xi_a, b_b, xi_b), translational rows in the level-n body frames; the stepper's own blocks),
    assembled in place.  ``cs``: complex scratch (varint.terms.rod._element_scratch layout, then ra, rb, xa, xb, qa,
    qb); ``col`` (>= 12) real scratch.  Returns False if not finite."""
    N = Lam_n.shape[0] - 1
    kv = kl + ku
    ab[:, :] = 0.0
    blk = np.empty((12, 12))
    ok = True
    for e in range(N):
        k_step_block(h, ds, rhoA, inertia, Jd, Kd, g, paper, Lam_n, r_n, xi, r_1, e, cmask, EPS_CS, cs, col[:12], blk)
        for k in range(12):
            if not cmask[e + k // 6, k % 6]:
                continue
            kc = idx[e + k // 6, k % 6]
            if kc < 0:
                continue
            pc = bpos[kc]
            for a in range(12):
                ka = idx[e + a // 6, a % 6]
                if ka < 0:
                    continue
                v = blk[a, k]
                if not np.isfinite(v):
                    ok = False
                ab[pc, kv + bpos[ka] - pc] += v
    return ok


@njit(cache=True, error_model="numpy")
def _k_band_jacobian_fd(h, ds, rhoA, inertia, Jd, Kd, g, force, torque, paper, periodic, Lam_n, r_n, pin, z, idx, bpos,
                        kl, ku, scale, color, ncolor, xi, r_1, dr, D, M, V, e1, e2, r0, zp, rp, ab):
    """The step's Jacobian at z by forward differences of the compiled residual, coloured (Curtis, Powell & Reid,
    IMA J. Appl. Math. 13, 1974): a node's rows depend only on its own and its two neighbours' unknowns, so one
    direction of every node of one colour (nodes two or fewer places apart, around a period, differ in colour) is
    perturbed at once and each difference is read off in the rows of the perturbed node and its neighbours: 3 d
    residuals (d directions per node; a periodic rod whose node count is no multiple of 3, 4 d) instead of the
    complex steps of every element column (~40 residuals, ``_k_band_jacobian``).  Step FD_STEP x scale, taken as the
    representable difference zp - z.  r0 receives the residual at z (band order), the chord iteration's first.
    Returns the number of residuals evaluated, negated if one is not finite."""
    n1 = idx.shape[0]
    N = n1 - 1
    nn = N if periodic else n1
    n = z.shape[0]
    kv = kl + ku
    ab[:, :] = 0.0
    if not _k_residual(h, ds, rhoA, inertia, Jd, Kd, g, force, torque, paper, periodic, Lam_n, r_n, pin, z, idx, bpos,
                       xi, r_1, dr, D, M, V, e1, e2, r0):
        return -1
    count = 1
    for c in range(ncolor):
        for comp in range(6):
            for k in range(n):
                zp[k] = z[k]
            moved = False
            for j in range(nn):
                k = idx[j, comp]
                if color[j] == c and k >= 0:
                    zp[k] = z[k] + FD_STEP * scale[k]
                    moved = True
            if not moved:
                continue
            count += 1
            if not _k_residual(h, ds, rhoA, inertia, Jd, Kd, g, force, torque, paper, periodic, Lam_n, r_n, pin, zp, idx,
                               bpos, xi, r_1, dr, D, M, V, e1, e2, rp):
                return -count
            for j in range(nn):
                kc = idx[j, comp]
                if color[j] != c or kc < 0:
                    continue
                inv = 1.0 / (zp[kc] - z[kc])
                pc = bpos[kc]
                for o in range(-1, 2):
                    i = j + o
                    if periodic:
                        i = (i + N) % N
                    elif i < 0 or i > N:
                        continue
                    for rc in range(6):
                        kr = idx[i, rc]
                        if kr >= 0:
                            pr = bpos[kr]
                            ab[pc, kv + pr - pc] = (rp[pr] - r0[pr]) * inv
    return count


@njit(cache=True, error_model="numpy")
def _k_floor_ok(dz, z, scale):
    """Every update within ROUNDOFF_BAND of its kind's round-off floor (varint.schemes.newton._within_floor; the rod's
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


@njit(cache=True, inline="always", error_model="numpy")
def _k_stats(stats, converged, iterations, n_res, n_jac, err, factor_valid, code):
    stats[7] = -1.0
    stats[0] = converged
    stats[1] = iterations
    stats[2] = n_res
    stats[3] = n_jac
    stats[4] = err
    stats[5] = factor_valid
    stats[6] = code


@njit(cache=True, error_model="numpy")
def _k_step(h, ds, rhoA, inertia, Jd, Kd, g, force, torque, paper, periodic, Lam_n, r_n, pin, idx, cmask, bpos, kl, ku,
            scale, tol, max_iter, rate_refresh, polish, floor_est, z, dz, rb, xi, r_1, dr, D, M, V, e1, e2, cs, col, ab, ipiv,
            have_factor, fd_on, fd_now, color, ncolor, zp, rp, stats):
    """Newton's chord iteration of varint.schemes.newton.newton on the step residual, all compiled.

    ``z`` holds the predictor on entry and the solution on exit; ``ab``/``ipiv`` the factorisation, reused when
    ``have_factor``.  ``stats`` receives (converged, iterations, residuals, jacobians, error, factor valid, code,
    noise): code 0 converged, 1 not finite, 2 diverging, 3 no convergence, 4 singular; noise: the size of the update
    that stopped contracting while polishing (the measured round-off floor of the update), or -1.

    Rules beyond varint.schemes.newton.newton, all from ``floor_est`` (> 0: the round-off floor of the update measured on an
    earlier step, the size of an update that stopped contracting): (a) once ``tol`` is met (or ``100 tol`` when the
    floor itself is within 10x of tol, where the stepper accepts a stagnating update), the iteration stops when the
    next update predicted from the contraction rate, rate x err, is below the floor: the stepper would take that
    update and one or two more of round-off size to see that they stop shrinking; (b) an update within twice the
    floor that stops contracting is round-off: no new Jacobian is spent on it.

    ``fd_on``: every Jacobian is the coloured finite-difference one (``_k_band_jacobian_fd``; its base residual is
    the next iteration's), the exact one (complex steps) only where that is not finite or singular; ``fd_now``: first
    replace the inherited factorisation by one at the predictor (the refresh rule of ``_k_full_step``).  stats[10]:
    the finite-difference Jacobians made, stats[11]: the iteration at which the last Jacobian was made (-1: none)."""
    n = z.shape[0]
    n_res = 0
    n_jac = 0
    jac_iter = -1  # -1: inherited factorisation
    stats[10] = 0.0
    stats[11] = -1.0
    first_ready = False
    pending = fd_on and fd_now and have_factor  # the scheduled refresh, after the first update
    if fd_on and not have_factor:
        m = _k_band_jacobian_fd(h, ds, rhoA, inertia, Jd, Kd, g, force, torque, paper, periodic, Lam_n, r_n, pin, z, idx,
                                bpos, kl, ku, scale, color, ncolor, xi, r_1, dr, D, M, V, e1, e2, rb, zp, rp, ab)
        n_res += abs(m)
        have_factor = m > 0 and _k_band_lu(ab, kl, ku, ipiv) == 0
        if have_factor:
            stats[10] += 1.0
            stats[11] = 0.0
            jac_iter = 0
            first_ready = True  # rb holds the residual at the predictor
    if not have_factor:
        stats[11] = 0.0
        _k_chart(Lam_n, r_n, z, idx, periodic, xi, r_1, dr)
        ok = _k_band_jacobian(h, ds, rhoA, inertia, Jd, Kd, g, paper, Lam_n, r_n, xi, r_1, cmask, idx, bpos, kl, ku,
                              cs, col, ab)
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
        if first_ready:
            first_ready = False
        else:
            ok = _k_residual(h, ds, rhoA, inertia, Jd, Kd, g, force, torque, paper, periodic, Lam_n, r_n, pin, z, idx,
                             bpos, xi, r_1, dr, D, M, V, e1, e2, rb)
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
        if floor_est > 0.0 and err_prev > 0.0 and (err / err_prev) * err <= floor_est and (
                err <= tol or (err <= 100.0 * tol and 10.0 * floor_est >= tol)):
            _k_stats(stats, 1, it, n_res, n_jac, err, 1, 0)  # (a) the next update would be round-off
            return
        if err <= tol or err <= floor:
            contracting = polished == 0 or err < 0.7 * err_prev
            if polished < polish and err > floor and contracting:
                polished += 1
                err_prev = err
                continue
            _k_stats(stats, 1, it, n_res, n_jac, err, 1, 0)
            if not contracting:
                stats[7] = err
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
                    stats[7] = err
                    return
                if STAGNATION_RATE <= rate < MAX_ROUNDOFF_RATE and rate_prev <= rate_refresh:
                    if _k_floor_ok(dz, z, scale):
                        _k_stats(stats, 1, it, n_res, n_jac, err, 1, 0)  # stopped at the round-off floor
                        stats[7] = err
                        return
                    if err <= 2.0 * floor_est:  # (b); not recorded as a new floor (it would ratchet up)
                        _k_stats(stats, 1, it, n_res, n_jac, err, 1, 0)
                        return
                growing = (not np.isfinite(rate)) or rate >= 1.0
                n_growing = n_growing + 1 if growing else 0
                if n_growing >= 3:
                    _k_stats(stats, 0, it, n_res, n_jac, err, 1, 2)
                    return
                if jac_iter < it:
                    jac_iter = it
                    err_prev = -1.0
                    rate_prev = np.nan
                    stats[11] = it
                    if fd_on:
                        m = _k_band_jacobian_fd(h, ds, rhoA, inertia, Jd, Kd, g, force, torque, paper, periodic, Lam_n,
                                                r_n, pin, z, idx, bpos, kl, ku, scale, color, ncolor, xi, r_1, dr, D, M,
                                                V, e1, e2, rb, zp, rp, ab)
                        n_res += abs(m)
                        if m > 0 and _k_band_lu(ab, kl, ku, ipiv) == 0:
                            stats[10] += 1.0
                            first_ready = True  # rb holds the residual at z
                            continue
                    _k_chart(Lam_n, r_n, z, idx, periodic, xi, r_1, dr)
                    ok = _k_band_jacobian(h, ds, rhoA, inertia, Jd, Kd, g, paper, Lam_n, r_n, xi, r_1, cmask, idx, bpos,
                                          kl, ku, cs, col, ab)
                    n_jac += 1
                    if not ok or _k_band_lu(ab, kl, ku, ipiv) != 0:
                        _k_stats(stats, 0, it, n_res, n_jac, err, 0, 4)
                        return
                    continue
            rate_prev = rate
        err_prev = err
        if pending:  # the scheduled refresh at z_1: a better point than the predictor where J depends on z
            pending = False
            m = _k_band_jacobian_fd(h, ds, rhoA, inertia, Jd, Kd, g, force, torque, paper, periodic, Lam_n, r_n, pin, z,
                                    idx, bpos, kl, ku, scale, color, ncolor, xi, r_1, dr, D, M, V, e1, e2, rb, zp, rp, ab)
            n_res += abs(m)
            if m < 0 or _k_band_lu(ab, kl, ku, ipiv) != 0:
                _k_stats(stats, 0, it, n_res, n_jac, err, 0, 4)
                return
            stats[10] += 1.0
            stats[11] = 0.0
            jac_iter = it
            err_prev = -1.0
            rate_prev = np.nan
            first_ready = True  # rb holds the residual at z


@njit(cache=True, error_model="numpy")
def _k_finish(h, ds, rhoA, inertia, Jd, Kd, g, force, torque, paper, periodic, floating, period, Lam_n, r_n, origin, z, idx,
              xi, r_1, dr, D, M, V, e1, e2, C, q1, p1, v1, turn):
    """The accepted step's new level: q_{n+1} (Step.retract: frames re-orthonormalised by one polar Newton step, a
    periodic image node, the floating origin on its binary grid), pi_{n+1} = fold(D2 L_d + f^+) (Step.momentum_plus)
    and the predictor's data v = (Lambda_n^T (r_1 - r_n), xi) (Simulation._step_velocity).  turn[0:2] = the largest
    |xi| and its node."""
    N = Lam_n.shape[0] - 1
    n1 = N + 1
    _k_chart(Lam_n, r_n, z, idx, periodic, xi, r_1, dr)
    turn[0] = 0.0
    turn[1] = 0.0
    for j in range(n1):
        t = math.sqrt(xi[j, 0] ** 2 + xi[j, 1] ** 2 + xi[j, 2] ** 2)
        if t > turn[0]:
            turn[0] = t
            turn[1] = j
    k_rod_gradient(h, ds, rhoA, inertia, Jd, Kd, g, force, paper, Lam_n, r_n, xi, dr, 1, 2, D, D, M, V, e1, e2, False)
    # the new frames: Lambda_n cay(xi), then one polar Newton step L (3 I - L^T L) / 2 (varint.terms.rod.reorthonormalize)
    L1 = q1[3 * n1:12 * n1].reshape(n1, 3, 3)
    T = M[4]  # (element scratch, free here)
    for j in range(n1):
        k_cay(xi[j, 0], xi[j, 1], xi[j, 2], C)
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
    k_tip_torque(0.5 * h, L1[N], torque, D[N, 3:])
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


@njit(cache=True, inline="always", error_model="numpy")
def _k_polish_node(j, ca, cb, h, ds, rhoA, inertia, g, Lam_n, r_n, pin, xi, dr, G, A, B, AB):
    """Node j's terms added to the closed-form balances (G's last column: P then J) and to their derivative G[:, :6]
    along a rigid motion (a, w) of level n+1 (see _k_rigid_system).  ca, cb: c = h ds mu of the elements before and
    after the node (0 where there is none).  The inertial and weight terms are written as the element kernel writes
    them (``k_element``, level n), with the same constant factors: a product such as c/h^2 rounded differently would
    be a fixed relative error of the masses, i.e. a bias eps |J| per step.  Each node's momentum and inertial terms are
    combined before they are summed: they nearly cancel (their difference is the node's internal force impulse), and
    the running sums then stay small."""
    ih2 = 1.0 / (h * h)
    m = rhoA * (ca + cb) / (2.0 * h)  # the lumped mass, for the derivative only
    r0, r1, r2 = r_n[j, 0], r_n[j, 1], r_n[j, 2]
    q0, q1, q2 = r0 + dr[j, 0], r1 + dr[j, 1], r2 + dr[j, 2]
    # translational: f = p + sum_e c (rhoA g/4 - rhoA dr/(2 h^2)) (= p - m dr/h + h m g/2), P += f, J += r_n x f
    f0 = pin[j, 0] + ca * (0.25 * rhoA * g[0] - 0.5 * rhoA * dr[j, 0] * ih2) + cb * (
        0.25 * rhoA * g[0] - 0.5 * rhoA * dr[j, 0] * ih2)
    f1 = pin[j, 1] + ca * (0.25 * rhoA * g[1] - 0.5 * rhoA * dr[j, 1] * ih2) + cb * (
        0.25 * rhoA * g[1] - 0.5 * rhoA * dr[j, 1] * ih2)
    f2 = pin[j, 2] + ca * (0.25 * rhoA * g[2] - 0.5 * rhoA * dr[j, 2] * ih2) + cb * (
        0.25 * rhoA * g[2] - 0.5 * rhoA * dr[j, 2] * ih2)
    G[0, 6] += f0
    G[1, 6] += f1
    G[2, 6] += f2
    G[3, 6] += r1 * f2 - r2 * f1
    G[4, 6] += r2 * f0 - r0 * f2
    G[5, 6] += r0 * f1 - r1 * f0
    # the balances change by -(1/h) G (a, w):  G = [[M I, -hat(S1)], [hat(S0), sum m ((r.q) I - q r^T) + ...]],
    # S0 = sum m r_n, S1 = sum m q, q = r_n + dr
    for i in range(3):
        G[i, i] += m
    G[0, 4] += m * q2
    G[0, 5] += -m * q1
    G[1, 3] += -m * q2
    G[1, 5] += m * q0
    G[2, 3] += m * q1
    G[2, 4] += -m * q0
    G[3, 1] += -m * r2
    G[3, 2] += m * r1
    G[4, 0] += m * r2
    G[4, 2] += -m * r0
    G[5, 0] += -m * r1
    G[5, 1] += m * r0
    rq = r0 * q0 + r1 * q1 + r2 * q2
    for a in range(3):
        G[3 + a, 3 + a] += m * rq
        for b in range(3):
            G[3 + a, 3 + b] -= m * (q0 if a == 0 else (q1 if a == 1 else q2)) * r_n[j, b]
    # rotational: k(xi) = (dcay^-1_xi)^T I xi = I xi + xi x I xi / 2 + (xi.I xi) xi / 4;  J += Lambda_n (Pi - k/h)
    # (the kernel's order: tmp = _k_dcinvT(xi, inertia xi, +1), D += (-0.5 c) ih2 tmp per element)
    x0, x1, x2 = xi[j, 0], xi[j, 1], xi[j, 2]
    y0, y1, y2 = inertia[0] * x0, inertia[1] * x1, inertia[2] * x2
    wv = 0.25 * (x0 * y0 + x1 * y1 + x2 * y2)
    t0 = y0 + 0.5 * (x1 * y2 - x2 * y1) + wv * x0
    t1 = y1 + 0.5 * (x2 * y0 - x0 * y2) + wv * x1
    t2 = y2 + 0.5 * (x0 * y1 - x1 * y0) + wv * x2
    k0 = pin[j, 3] + -0.5 * ca * ih2 * t0 + -0.5 * cb * ih2 * t0
    k1 = pin[j, 4] + -0.5 * ca * ih2 * t1 + -0.5 * cb * ih2 * t1
    k2 = pin[j, 5] + -0.5 * ca * ih2 * t2 + -0.5 * cb * ih2 * t2
    om = (ca + cb) / (2.0 * h)
    I0, I1, I2 = inertia[0] * om, inertia[1] * om, inertia[2] * om
    y0, y1, y2 = I0 * x0, I1 * x1, I2 * x2
    xy = x0 * y0 + x1 * y1 + x2 * y2
    for a in range(3):
        G[3 + a, 6] += Lam_n[j, a, 0] * k0 + Lam_n[j, a, 1] * k1 + Lam_n[j, a, 2] * k2
    # dk/dxi = I - hat(I xi)/2 + hat(xi) I/2 + xi (I xi)^T/2 + (xi.I xi)/4 Id;  dxi/dw = dcay^-1_xi Lambda_n^T w,
    # dcay^-1_xi = Id - hat(xi)/2 + xi xi^T/4;  dJ/dw += Lambda_n (dk/dxi) dcay^-1_xi Lambda_n^T
    A[0, 0] = I0 + 0.5 * x0 * y0 + 0.25 * xy
    A[0, 1] = 0.5 * y2 - 0.5 * x2 * I1 + 0.5 * x0 * y1
    A[0, 2] = -0.5 * y1 + 0.5 * x1 * I2 + 0.5 * x0 * y2
    A[1, 0] = -0.5 * y2 + 0.5 * x2 * I0 + 0.5 * x1 * y0
    A[1, 1] = I1 + 0.5 * x1 * y1 + 0.25 * xy
    A[1, 2] = 0.5 * y0 - 0.5 * x0 * I2 + 0.5 * x1 * y2
    A[2, 0] = 0.5 * y1 - 0.5 * x1 * I0 + 0.5 * x2 * y0
    A[2, 1] = -0.5 * y0 + 0.5 * x0 * I1 + 0.5 * x2 * y1
    A[2, 2] = I2 + 0.5 * x2 * y2 + 0.25 * xy
    B[0, 0] = 1.0 + 0.25 * x0 * x0
    B[0, 1] = 0.5 * x2 + 0.25 * x0 * x1
    B[0, 2] = -0.5 * x1 + 0.25 * x0 * x2
    B[1, 0] = -0.5 * x2 + 0.25 * x1 * x0
    B[1, 1] = 1.0 + 0.25 * x1 * x1
    B[1, 2] = 0.5 * x0 + 0.25 * x1 * x2
    B[2, 0] = 0.5 * x1 + 0.25 * x2 * x0
    B[2, 1] = -0.5 * x0 + 0.25 * x2 * x1
    B[2, 2] = 1.0 + 0.25 * x2 * x2
    for a in range(3):
        for b in range(3):
            AB[a, b] = A[a, 0] * B[0, b] + A[a, 1] * B[1, b] + A[a, 2] * B[2, b]
    for a in range(3):  # A <- Lambda_n AB
        for b in range(3):
            A[a, b] = Lam_n[j, a, 0] * AB[0, b] + Lam_n[j, a, 1] * AB[1, b] + Lam_n[j, a, 2] * AB[2, b]
    for a in range(3):  # + A Lambda_n^T
        for b in range(3):
            G[3 + a, 3 + b] += A[a, 0] * Lam_n[j, b, 0] + A[a, 1] * Lam_n[j, b, 1] + A[a, 2] * Lam_n[j, b, 2]


@njit(cache=True, error_model="numpy")
def _k_rigid_system(h, ds, rhoA, inertia, g, force, torque, paper, Lam_n, r_n, pin, xi, dr, M, G):
    """The step's linear and angular momentum balances in closed form, into G[:, 6] (docs/theory.md §9, "Momenta to
    round-off"):

        P(z) = sum_j [p_j - m_j dr_j/h + h m_j g/2] + h F/2,
        J(z) = sum_j [r_j x (p_j - m_j dr_j/h + h m_j g/2) + Lambda_j (Pi_j - k(xi_j)/h)] + r_N x h F/2 + h T/2,

    the sums of the residual's rows (spatial) and their moments without the internal forces, whose sums vanish
    identically (L_d's strains at each level are invariant under a rigid motion of that level).  Newton leaves every
    row at its round-off floor, that of the stiff forces (h K eps |chord| / ds); in these six directions the balances
    can be met to the round-off of the momenta.  m_j, I_j: the lumped mass and inertia of node j (rho A, the section inertia
    times ds (mu_{j-1} + mu_j)/2; mu = 1, or |Gamma_bar| for the paper's measure), k(xi) = (dcay^-1_xi)^T I xi.
    G[:, :6]: their derivative along a rigid motion (a, w) of level n+1 (_k_rigid_polish), times -h.  ``xi``, ``dr``:
    the chart of z (_k_chart); ``M`` (>= 4, 3, 3) real scratch; ``G`` (6, 7)."""
    N = Lam_n.shape[0] - 1
    A, B, AB, C = M[0], M[1], M[2], M[3]
    for a in range(6):
        for b in range(7):
            G[a, b] = 0.0
    for j in range(N + 1):
        # c = h ds mu of the elements before and after node j (the element kernel's factor)
        ca = 0.0
        cb = 0.0
        if j > 0:
            ca = h * ds * (k_measure(j - 1, ds, Lam_n, r_n, xi, dr, A, B, C) if paper else 1.0)
        if j < N:
            cb = h * ds * (k_measure(j, ds, Lam_n, r_n, xi, dr, A, B, C) if paper else 1.0)
        _k_polish_node(j, ca, cb, h, ds, rhoA, inertia, g, Lam_n, r_n, pin, xi, dr, G, A, B, AB)
    # the loads' halves at the tip: h F / 2 at r_N, f^- of the tip torque (Lambda_N f^- = h T / 2)
    f0, f1, f2 = 0.5 * h * force[0], 0.5 * h * force[1], 0.5 * h * force[2]
    G[0, 6] += f0
    G[1, 6] += f1
    G[2, 6] += f2
    G[3, 6] += r_n[N, 1] * f2 - r_n[N, 2] * f1 + 0.5 * h * torque[0]
    G[4, 6] += r_n[N, 2] * f0 - r_n[N, 0] * f2 + 0.5 * h * torque[1]
    G[5, 6] += r_n[N, 0] * f1 - r_n[N, 1] * f0 + 0.5 * h * torque[2]


@njit(cache=True, error_model="numpy")
def _k_rigid_polish(h, ds, rhoA, inertia, g, force, torque, paper, Lam_n, r_n, pin, z, idx, xi, dr, M, G):
    """One Newton correction of the step's solution z in the six rigid directions of level n+1 that zeroes the
    closed-form momentum balances of :func:`_k_rigid_system` (docs/theory.md §9, "Momenta to round-off").  The motion
    (a, w): dr_j += a + w x (r_j + dr_j), Lambda_j^{n+1} <- (I + hat(w)) Lambda_j^{n+1}, i.e. b_j += Lambda_j^T (a +
    w x (r_j + dr_j)), xi_j += dcay^-1_{xi_j} Lambda_j^T w; it leaves the strains of level n+1, hence the elastic
    rows, unchanged, and it is of the size of the residual's floor.  Free open rods only (a support or a period breaks
    the symmetry); off the mask (out of a planar rod's plane) the correction is zero.  Returns the largest change of a
    b unknown (a diagnostic), or -1 if the 6x6 system is singular (z unchanged)."""
    N = Lam_n.shape[0] - 1
    _k_rigid_system(h, ds, rhoA, inertia, g, force, torque, paper, Lam_n, r_n, pin, xi, dr, M, G)
    # G x = h (P, J): Gaussian elimination with partial pivoting
    for c in range(6):
        G[c, 6] *= h
    for c in range(6):
        p = c
        for r in range(c + 1, 6):
            if abs(G[r, c]) > abs(G[p, c]):
                p = r
        if G[p, c] == 0.0:
            return -1.0
        if p != c:
            for k in range(c, 7):
                t = G[c, k]
                G[c, k] = G[p, k]
                G[p, k] = t
        for r in range(c + 1, 6):
            f = G[r, c] / G[c, c]
            if f != 0.0:
                for k in range(c, 7):
                    G[r, k] -= f * G[c, k]
    for c in range(5, -1, -1):
        s = G[c, 6]
        for k in range(c + 1, 6):
            s -= G[c, k] * G[k, 6]
        G[c, 6] = s / G[c, c]
    a0, a1, a2, w0, w1, w2 = G[0, 6], G[1, 6], G[2, 6], G[3, 6], G[4, 6], G[5, 6]
    # apply on the unknowns (off the mask, i.e. out of a planar rod's plane, the correction is zero)
    size = 0.0
    for j in range(N + 1):
        q0, q1, q2 = r_n[j, 0] + dr[j, 0], r_n[j, 1] + dr[j, 1], r_n[j, 2] + dr[j, 2]
        u0 = a0 + w1 * q2 - w2 * q1
        u1 = a1 + w2 * q0 - w0 * q2
        u2 = a2 + w0 * q1 - w1 * q0
        x0, x1, x2 = xi[j, 0], xi[j, 1], xi[j, 2]
        for i in range(3):
            k = idx[j, i]
            if k >= 0:
                d = Lam_n[j, 0, i] * u0 + Lam_n[j, 1, i] * u1 + Lam_n[j, 2, i] * u2
                z[k] += d
                size = max(size, abs(d))
        s0 = Lam_n[j, 0, 0] * w0 + Lam_n[j, 1, 0] * w1 + Lam_n[j, 2, 0] * w2
        s1 = Lam_n[j, 0, 1] * w0 + Lam_n[j, 1, 1] * w1 + Lam_n[j, 2, 1] * w2
        s2 = Lam_n[j, 0, 2] * w0 + Lam_n[j, 1, 2] * w1 + Lam_n[j, 2, 2] * w2
        xs = 0.25 * (x0 * s0 + x1 * s1 + x2 * s2)
        t0 = s0 - 0.5 * (x1 * s2 - x2 * s1) + xs * x0
        t1 = s1 - 0.5 * (x2 * s0 - x0 * s2) + xs * x1
        t2 = s2 - 0.5 * (x0 * s1 - x1 * s0) + xs * x2
        for i in range(3):
            k = idx[j, 3 + i]
            if k >= 0:
                d = t0 if i == 0 else (t1 if i == 1 else t2)
                z[k] += d
    return size


@njit(cache=True, error_model="numpy")
def _k_full_step(cf, cv, ci, idx, cmask, bpos, vsel, scale, color, Lam_n, r_n, origin, p, v, vprev, q1, p1, v1, wz, wn, wd,
                 rM, rV, re, cM, cV, ce, col, ab, ipiv, G, stats):
    """One whole step, one call (few array arguments: a numba call costs per argument).

    cf = [h, ds, rhoA, tol, rate_refresh, floor_est]; cv rows = inertia, J, K, g, tip force, tip torque, period;
    ci = [paper, periodic, floating, kl, ku, max_iter, polish, have_factor, linear predictor, steps to recalibrate,
    rigid polish, finite-difference Jacobians on, colours]; cf[6:9] = the refresh rule's excess iterations, the
    fewest iterations of a step on the current factorisation (-1: none yet) and the refresh's cost in iterations
    (docs/theory.md §9, "Jacobian refresh").  Predictor: z = v (the last step's b, xi on the mask) or 2 v - v_prev;
    then _k_step, then (a free rod, ci[10]) _k_rigid_polish and _k_finish when it converged.  cf[5:8] and ci[7], ci[9]
    are updated in place; G (6, 7): the rigid polish's system."""
    n1 = Lam_n.shape[0]
    h, ds, rhoA, tol, rate_refresh = cf[0], cf[1], cf[2], cf[3], cf[4]
    inertia, Jd, Kd, g, force, torque, period = cv[0], cv[1], cv[2], cv[3], cv[4], cv[5], cv[6]
    paper, periodic, floating = ci[0] != 0, ci[1] != 0, ci[2] != 0
    z, dz, rb, zp, rp = wz[0], wz[1], wz[2], wz[3], wz[4]
    xi, r_1, dr = wn[0], wn[1], wn[2]
    D, pin = wd[0], wd[1]
    for k in range(z.shape[0]):
        z[k] = 2.0 * v[vsel[k]] - vprev[vsel[k]] if ci[8] != 0 else v[vsel[k]]
    for j in range(n1):
        for i in range(3):
            pin[j, i] = p[3 * j + i]
            pin[j, 3 + i] = p[3 * n1 + 3 * j + i]
    floor_est = cf[5] if ci[9] > 0 else -1.0
    cs = (cM[0:5], cV[0:16], ce[0], ce[1], cM[5], cM[6], cV[16], cV[17], cV[18], cV[19], cV[20], cV[21])
    M, V, e1, e2 = rM[0:5], rV, re[0], re[1]
    # the refresh rule (docs/theory.md §9, "Jacobian refresh"): a finite-difference Jacobian once the iterations the
    # steps have spent beyond the first step on the current factorisation add up to the refresh's cost
    fd_now = ci[11] != 0 and ci[7] != 0 and cf[8] > 0.0 and cf[6] >= cf[8]
    _k_step(h, ds, rhoA, inertia, Jd, Kd, g, force, torque, paper, periodic, Lam_n, r_n, pin, idx, cmask, bpos, ci[3],
            ci[4], scale, tol, ci[5], rate_refresh, ci[6], floor_est, z, dz, rb, xi, r_1, dr, D, M, V, e1, e2, cs, col, ab,
            ipiv, ci[7] != 0, ci[11] != 0, fd_now, color, ci[12], zp, rp, stats)
    ci[7] = 1 if stats[5] != 0.0 else 0
    if stats[11] == 0.0:  # a Jacobian at the predictor: this step's count is the new factorisation's base
        cf[6] = 0.0
        cf[7] = stats[1]
    elif stats[11] > 0.0:  # a Jacobian within the step: the next step's count is the base
        cf[6] = 0.0
        cf[7] = -1.0
    else:  # the base is the fewest iterations a step has taken on this factorisation (the first step from rest, or
        # after a jump, can take more than the later ones)
        if cf[7] < 0.0 or stats[1] < cf[7]:
            cf[7] = stats[1]
        cf[6] += stats[1] - cf[7]
    if stats[7] > 0.0:  # a measured round-off floor: recalibrate every 64 steps
        cf[5] = stats[7]
        ci[9] = 64
    elif ci[9] > 0:
        ci[9] -= 1
    if stats[0] == 0.0:
        return
    if ci[10] != 0:
        _k_chart(Lam_n, r_n, z, idx, periodic, xi, r_1, dr)
        _k_rigid_polish(h, ds, rhoA, inertia, g, force, torque, paper, Lam_n, r_n, pin, z, idx, xi, dr, M, G)
    _k_finish(h, ds, rhoA, inertia, Jd, Kd, g, force, torque, paper, periodic, floating, period, Lam_n, r_n, origin, z,
              idx, xi, r_1, dr, D, M, V, e1, e2, rM[5], q1, p1, v1, stats[8:10])


class FastRodStep:
    """The compiled rod step (module docstring): ``step(state) -> new State``, the stepper's equations.

    ``tol``, ``max_iter``: Newton's (default: the scene's ``time.newton_tol`` and ``max(time.max_iterations,
    40)``, as :class:`varint.run.simulation.Simulation`); ``predictor``: "constant" (the last step's (b, xi), the
    stepper's; default) or "linear" (the last two steps' extrapolated).  ``early_stop``: stop once the next update
    predicted from the contraction rate is below the round-off floor measured on an earlier step (``_k_step``);
    False polishes every step exactly as the stepper does.  ``rate_refresh``: the contraction rate above which the
    Jacobian is refreshed (``RATE_REFRESH_FAST``; the stepper's ``RATE_REFRESH_ROD`` repeats its choices).
    ``fd_refresh``: also refresh the factorisation with the coloured finite-difference Jacobian at a step's predictor
    once the iterations spent beyond the first step on the current one add up to ``refresh_cost`` iterations (default:
    the refresh's own cost, from LU_SOLVE_COST; docs/theory.md §9, "Jacobian refresh"); False: the rate rule alone.
    """

    def __init__(self, model, h=None, tol=None, max_iter=None, predictor="constant", early_stop=True,
                 rate_refresh=RATE_REFRESH_FAST, fd_refresh=True, refresh_cost=None):
        why = supports(model)
        if why is not None:
            raise SolverError(f"rod step: the fast path does not run this model ({why})")
        if predictor not in ("linear", "constant"):
            raise ValueError(f"predictor: {predictor!r} is not 'linear' or 'constant'")
        rod = model.rod
        tcfg = model.scene.time
        self.model, self.rod = model, rod
        self.h = float(h if h is not None else tcfg.step)
        self.tol = float(tol if tol is not None else tcfg.newton_tol)
        self.max_iter = int(max(max_iter if max_iter is not None else tcfg.max_iterations, 40))
        self.predictor, self.early_stop = predictor, bool(early_stop)
        N = rod.N
        n1 = N + 1
        self.n1 = n1
        _, rhoA, inertia, J, K, g, force = rod._consts()
        torque = np.zeros(3)
        for f in model.forces:
            torque = torque + f.torque
        self.idx = np.ascontiguousarray(rod.node_index(), dtype=np.int64)
        self.cmask = np.ascontiguousarray(rod.column_mask)
        nz = rod.nz
        self.nz = nz
        # band order: node-major (z's own order) for open ends; a periodic rod's nodes interleaved 0, 1, N-1, 2, N-2, ...
        # so that the wrap-around element (N-1, N = image of 0) stays within a few nodes of the diagonal
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
            self.bpos = np.ascontiguousarray(node_pos[np.repeat(np.arange(N), per_node)] * per_node
                                             + np.tile(np.arange(per_node), N), dtype=np.int64)
        else:
            self.bpos = np.arange(nz, dtype=np.int64)
        rows, cols, _ = rod._block_pattern()
        d = self.bpos[rows] - self.bpos[cols]
        self.kl, self.ku = int(max(d.max(), 0)), int(max(-d.min(), 0))
        sc = np.ones((n1, 6))
        sc[:, :3] = rod.ds
        self.scale = np.ascontiguousarray(sc[rod.mask])  # Simulation._scales
        # where each unknown's last-step value sits in State.v ([b (n1, 3) | xi (n1, 3)]): the predictor
        vidx = np.empty((n1, 6), np.int64)
        vidx[:, :3] = 3 * np.arange(n1)[:, None] + np.arange(3)
        vidx[:, 3:] = 3 * n1 + 3 * np.arange(n1)[:, None] + np.arange(3)
        self.vsel = np.ascontiguousarray(vidx[rod.mask])
        # the finite-difference Jacobian's colours: nodes within two places of each other (around a period) differ.
        # 0, 1, 2, 0, 1, 2, ...; a period of N = 3a + 4b nodes: b blocks 0, 1, 2, 3 and a blocks 0, 1, 2 (4 colours)
        nn = N if rod.periodic else n1
        color = np.zeros(n1, np.int64)
        if rod.periodic and nn % 3 != 0:
            b4 = 1 if nn % 3 == 1 else 2
            if nn >= 4 * b4:
                color[:nn] = [0, 1, 2, 3] * b4 + [0, 1, 2] * ((nn - 4 * b4) // 3)
            else:  # N = 2 or 5: every node its own colour
                color[:nn] = np.arange(nn)
        else:
            color[:nn] = np.arange(nn) % 3
        self.color = color
        ncolor = int(color[:nn].max()) + 1
        d = int(rod.mask[0].sum()) if rod.periodic else int(rod.mask.sum(axis=1).max())
        if refresh_cost is None:
            lu, solve = LU_SOLVE_COST.get(d, LU_SOLVE_COST[6])
            refresh_cost = (ncolor * d + lu) / (1.0 + solve)
        self.refresh_cost = float(refresh_cost)
        # constants and preallocated buffers (reused by every step and every iteration)
        self.cf = np.array([self.h, rod.ds, float(rhoA), self.tol, float(rate_refresh), -1.0, 0.0, -1.0,
                            self.refresh_cost])
        self.cv = np.ascontiguousarray(np.stack([inertia, J, K, g, force, torque, rod.period]), dtype=float)
        # the rigid polish of the solution (docs/theory.md §9, "Momenta to round-off"): a free rod with open ends
        self.ci = np.array([rod.paper_measure, rod.periodic, rod.free, self.kl, self.ku, self.max_iter, POLISH_ROD, 0,
                            0, 0, rod.free and not rod.periodic, bool(fd_refresh), ncolor], dtype=np.int64)
        self.wz = np.zeros((5, nz))  # z, dz, the residual; the finite-difference Jacobian's z and residual
        self.wn = np.zeros((3, n1, 3))  # xi, r_1, dr
        self.wd = np.zeros((2, n1, 6))
        self.rM = np.zeros((6, 3, 3))
        self.rV = np.zeros((20, 3))  # the element kernel's scratch and an element's four positions
        self.re = np.zeros((2, 12))
        c = np.complex128
        self.cM = np.zeros((7, 3, 3), c)
        self.cV = np.zeros((22, 3), c)
        self.ce = np.zeros((2, 12), c)
        self.col = np.zeros(24)
        self.ab = np.zeros((nz, 2 * self.kl + self.ku + 1))
        self.ipiv = np.zeros(nz, np.int64)
        self.stats = np.zeros(12)
        self.G = np.zeros((6, 7))
        self._prev = None  # (n, v) of the state before, for the linear predictor
        self._step = None  # varint.schemes.midpoint.Step for the fallback, built on first need
        self.fallbacks = 0
        #: the last step's Newton counts (n_jacobian: every Jacobian made, n_jacobian_fd: the finite-difference ones
        #: among them), and whether it needed the stepper's damped Newton
        self.last = {"iterations": 0, "n_residual": 0, "n_jacobian": 0, "n_jacobian_fd": 0, "fallback": False}
        self._has_data = model.state_data() is not None

    @property
    def floating_origin(self):
        """Positions relative to a floating origin moved with node 0 (Simulation.floating_origin; default: a free rod)."""
        return bool(self.ci[2])

    @floating_origin.setter
    def floating_origin(self, on):
        self.ci[2] = 1 if on else 0

    @property
    def z(self):
        """The last step's solution (step unknowns in Step's order)."""
        return self.wz[0]

    def _consts(self):
        h, ds, rhoA = self.cf[:3]
        inertia, J, K, g, force, torque, period = self.cv
        return h, ds, rhoA, inertia, J, K, g, force, torque, bool(self.ci[0]), bool(self.ci[1])

    def _level(self, q):
        Lam, r, origin = unpack_level(q[self.model.rod_q], self.rod.N)
        return np.ascontiguousarray(Lam), np.ascontiguousarray(r), np.ascontiguousarray(origin)

    # -- the pieces, for tests ----------------------------------------------------------------------------------

    def residual(self, q0, p0, z):
        """The compiled step residual at z (Step.residual's order)."""
        Lam, r, _ = self._level(q0)
        pin = self._pin(p0)
        out = np.zeros(self.nz)
        h, ds, rhoA, inertia, J, K, g, force, torque, paper, periodic = self._consts()
        _k_residual(h, ds, rhoA, inertia, J, K, g, force, torque, paper, periodic, Lam, r, pin,
                    np.ascontiguousarray(z, dtype=float), self.idx, self.bpos, self.wn[0], self.wn[1], self.wn[2], self.wd[0],
                    self.rM[:5], self.rV, self.re[0], self.re[1], out)
        return out[self.bpos]

    def _pin(self, p0):
        pp = p0[self.model.rod_p]
        n1 = self.n1
        return np.ascontiguousarray(np.concatenate([pp[:3 * n1].reshape(n1, 3), pp[3 * n1:].reshape(n1, 3)], axis=1))

    def momentum_balances(self, q0, p0, z):
        """The step's linear and angular momentum balances at z in closed form (``_k_rigid_system``): (P, J), the
        moments about the level's (floating) origin."""
        Lam, r, _ = self._level(q0)
        z = np.ascontiguousarray(z, dtype=float)
        h, ds, rhoA, inertia, J, K, g, force, torque, paper, periodic = self._consts()
        xi, r_1, dr = np.zeros((3, self.n1, 3))
        _k_chart(Lam, r, z, self.idx, periodic, xi, r_1, dr)
        G = np.zeros((6, 7))
        _k_rigid_system(h, ds, rhoA, inertia, g, force, torque, paper, Lam, r, self._pin(p0), xi, dr, np.zeros((4, 3, 3)),
                        G)
        return G[:3, 6].copy(), G[3:, 6].copy()

    def polish(self, q0, p0, z):
        """z after the rigid polish of a step's solution (``_k_rigid_polish``; a free rod with open ends)."""
        Lam, r, _ = self._level(q0)
        z = np.array(z, dtype=float)
        h, ds, rhoA, inertia, J, K, g, force, torque, paper, periodic = self._consts()
        xi, r_1, dr = np.zeros((3, self.n1, 3))
        _k_chart(Lam, r, z, self.idx, periodic, xi, r_1, dr)
        _k_rigid_polish(h, ds, rhoA, inertia, g, force, torque, paper, Lam, r, self._pin(p0), z, self.idx, xi, dr,
                        np.zeros((4, 3, 3)), np.zeros((6, 7)))
        return z

    def jacobian(self, q0, z):
        """The compiled band Jacobian at z as a dense (nz, nz) array in z's order (Step.jacobian's)."""
        Lam, r, _ = self._level(q0)
        z = np.ascontiguousarray(z, dtype=float)
        h, ds, rhoA, inertia, J, K, g, force, torque, paper, periodic = self._consts()
        _k_chart(Lam, r, z, self.idx, periodic, self.wn[0], self.wn[1], self.wn[2])
        ab = np.zeros_like(self.ab)
        cs = (self.cM[0:5], self.cV[0:16], self.ce[0], self.ce[1], self.cM[5], self.cM[6]) + tuple(self.cV[16:22])
        _k_band_jacobian(h, ds, rhoA, inertia, J, K, g, paper, Lam, r, self.wn[0], self.wn[1], self.cmask, self.idx,
                         self.bpos, self.kl, self.ku, cs, self.col, ab)
        return self._band_to_dense(ab)

    def _band_to_dense(self, ab):
        """The band storage ``ab`` (band order) as a dense (nz, nz) array in z's order."""
        kv = self.kl + self.ku
        A = np.zeros((self.nz, self.nz))
        for jb in range(self.nz):
            for ib in range(max(0, jb - self.ku), min(self.nz, jb + self.kl + 1)):
                A[ib, jb] = ab[jb, kv + ib - jb]
        return A[np.ix_(self.bpos, self.bpos)]

    def jacobian_fd(self, q0, p0, z):
        """The coloured finite-difference band Jacobian at z (``_k_band_jacobian_fd``) as a dense (nz, nz) array in z's
        order; None if a residual is not finite."""
        Lam, r, _ = self._level(q0)
        z = np.ascontiguousarray(z, dtype=float)
        h, ds, rhoA, inertia, J, K, g, force, torque, paper, periodic = self._consts()
        ab = np.zeros_like(self.ab)
        r0, zp, rp = np.zeros((3, self.nz))
        m = _k_band_jacobian_fd(h, ds, rhoA, inertia, J, K, g, force, torque, paper, periodic, Lam, r, self._pin(p0), z,
                                self.idx, self.bpos, self.kl, self.ku, self.scale, self.color, int(self.ci[12]),
                                self.wn[0], self.wn[1], self.wn[2], self.wd[0], self.rM[:5], self.rV, self.re[0],
                                self.re[1], r0, zp, rp, ab)
        if m < 0:
            return None
        return self._band_to_dense(ab)

    # -- the step -------------------------------------------------------------------------------------------------

    def predict(self, state):
        """z0 (Python twin of the kernel's): the last step's (b, xi) on the mask, or (linear) 2 v_n - v_{n-1}."""
        v = state.v[self.model.rod_p]
        if self.predictor == "linear" and self._prev is not None and self._prev[0] == state.n - 1:
            return 2.0 * v[self.vsel] - self._prev[1][self.vsel]
        return v[self.vsel]

    def invalidate(self):
        """Forget the reused factorisation, the predictor's history and the measured floor
        (Simulation.invalidate_jacobian: a restart then repeats the same arithmetic)."""
        self.ci[7] = 0
        self.ci[9] = 0
        self.cf[5] = -1.0
        self.cf[6] = 0.0
        self.cf[7] = -1.0
        self._prev = None

    def _fallback(self, state, z0):
        """The stepper's damped Newton on varint.schemes.midpoint.Step (the same equations), from z0 and from rest."""
        from .midpoint import Step

        if self._step is None:
            self._step = Step(self.model, self.h)
        sch = self._step
        F = lambda z: sch.residual(state.q, state.p, z)  # noqa: E731
        Jf = lambda z: sch.jacobian(state.q, z)  # noqa: E731
        self.fallbacks += 1
        res = newton_damped(F, Jf, z0, self.scale, self.tol, 4 * self.max_iter)
        if not res.converged:
            res = newton_damped(F, Jf, np.zeros(self.nz), self.scale, self.tol, 4 * self.max_iter)
        self.ci[7] = 0
        return res

    def step(self, state):
        """The next level: a :class:`varint.schemes.state.State` as Simulation.step makes it (rod-only model)."""
        from .state import State

        m, n1 = self.model, self.n1
        n_new = state.n + 1
        q = state.q[m.rod_q]
        p = np.ascontiguousarray(state.p[m.rod_p])
        v = np.ascontiguousarray(state.v[m.rod_p])
        Lam, r, origin = q[3 * n1:12 * n1].reshape(n1, 3, 3), q[:3 * n1].reshape(n1, 3), q[12 * n1:]
        linear = self.predictor == "linear" and self._prev is not None and self._prev[0] == state.n - 1
        self.ci[8] = 1 if linear else 0
        if not self.early_stop:
            self.ci[9] = 0
        vprev = self._prev[1] if linear else v
        q1 = np.empty(12 * n1 + 3)
        p1 = np.empty(6 * n1)
        v1 = np.empty(6 * n1)
        st = self.stats
        _k_full_step(self.cf, self.cv, self.ci, self.idx, self.cmask, self.bpos, self.vsel, self.scale, self.color, Lam, r,
                     origin, p, v, vprev, q1, p1, v1, self.wz, self.wn, self.wd, self.rM, self.rV, self.re, self.cM, self.cV, self.ce,
                     self.col, self.ab, self.ipiv, self.G, st)
        iters, nres, njac = int(st[1]), int(st[2]), int(st[3]) + int(st[10])  # every Jacobian, exact or differenced
        fell_back = not st[0]
        if fell_back:
            z0 = 2.0 * v[self.vsel] - vprev[self.vsel] if linear else v[self.vsel]
            res = self._fallback(state, z0)
            iters, nres, njac = iters + res.iterations, nres + res.n_residual, njac + res.n_jacobian
            if not res.converged:
                where = f"step {n_new} (t = {n_new * self.h:.6g} s)"
                raise SolverError(f"Newton failed at {where}: {res.message}; scaled update {res.error:.3g} after "
                                  f"{iters} iterations; try a smaller time.step", step=n_new, time=n_new * self.h,
                                  residual=res.error, rate=res.rate)
            self.wz[0] = res.z
            h, ds, rhoA, inertia, J, K, g, force, torque, paper, periodic = self._consts()
            if self.ci[10]:  # the rigid polish, as after the compiled iteration (wd[1]: this step's pi_n)
                _k_chart(Lam, r, self.wz[0], self.idx, periodic, self.wn[0], self.wn[1], self.wn[2])
                _k_rigid_polish(h, ds, rhoA, inertia, g, force, torque, paper, Lam, r, self.wd[1], self.wz[0], self.idx,
                                self.wn[0], self.wn[2], self.rM, self.G)
            _k_finish(h, ds, rhoA, inertia, J, K, g, force, torque, paper, periodic, bool(self.ci[2]), self.cv[6], Lam,
                      r, origin, self.wz[0], self.idx, self.wn[0], self.wn[1], self.wn[2], self.wd[0], self.rM[:5], self.rV,
                      self.re[0], self.re[1], self.rM[5], q1, p1, v1, st[8:10])
        if st[8] > XI_MAX:
            self.ci[7] = 0
            raise chart_limit_error(m, n_new, self.h, int(st[9]), st[8])
        if self.predictor == "linear":
            self._prev = (state.n, v.copy())
        self.last = {"iterations": iters, "n_residual": nres, "n_jacobian": njac, "n_jacobian_fd": int(st[10]),
                     "fallback": fell_back}
        return State(n_new, n_new * self.h, q1, p1, np.zeros(0), v1, state.q.copy(),
                     m.state_data() if self._has_data else None)
