"""Newton iteration as a pure function returning its diagnostics.

Modelled on scipy's Radau/BDF solvers: the factorised Jacobian is reused across
calls (modified Newton) and refreshed only when the contraction rate says it is
stale; divergence is detected from the rate; counts of residual evaluations,
Jacobian evaluations and factorisations are returned so tests can bound them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

__all__ = ["NewtonResult", "newton", "factorize"]

EPS = np.finfo(float).eps
#: contraction rate above which the Jacobian is refreshed (a chord iteration that slow costs more than an LU)
RATE_REFRESH = 0.2
#: an update at least this fraction of the previous one has stopped contracting
STAGNATION_RATE = 0.5
#: updates within this factor of eps * max|state / scale| may be round-off (the measured floor of the tube's
#: step is 0.02-2 times eps max|state / scale| for 10^3-10^5 parcels and c h / ds = 0.2-17: a fraction of
#: an ulp of the absolute label positions, times the step's stiffness-to-mass ratio)
ROUNDOFF_BAND = 100.0
#: an update more than this many times the previous one is growth, not round-off (round-off updates
#: wander by a few times from one iteration to the next, they do not grow by orders)
MAX_ROUNDOFF_RATE = 10.0


@dataclass
class NewtonResult:
    converged: bool
    z: np.ndarray
    iterations: int
    error: float  #: last scaled update, max |dz / scale|
    rate: float  #: last observed contraction rate (nan if unknown)
    factor: object  #: the factorisation in use at the end (reuse it next time)
    n_residual: int
    n_jacobian: int
    message: str = ""


class _Diagonal:
    def __init__(self, d):
        self.inv = 1.0 / d

    def solve(self, r):
        return self.inv * r


def factorize(J):
    """LU of a sparse Jacobian (or a cheap inverse when it is diagonal); None if singular or not finite."""
    J = sp.csc_matrix(J)
    if not np.all(np.isfinite(J.data)):
        return None
    if J.nnz == np.count_nonzero(J.diagonal()) and J.nnz == J.shape[0]:
        return _Diagonal(J.diagonal())
    try:
        return spla.splu(J)
    except RuntimeError:  # exactly singular
        return None


def _singular(J):
    """Why :func:`factorize` gave no factor."""
    return "Jacobian is not finite" if not np.all(np.isfinite(sp.csc_matrix(J).data)) else "singular Jacobian"


def _within_floor(dz, z, mag, scale):
    """Is every update within ROUNDOFF_BAND of the round-off floor of its kind of unknown?

    A kind is the set of unknowns sharing one scale; its floor is eps max|z + offset| / scale over
    the kind (round-off of a label's residual comes from its neighbours' positions as much as from its own).
    """
    kinds, which = np.unique(scale, return_inverse=True)
    size = np.zeros(len(kinds))
    np.maximum.at(size, which, (np.abs(z) + mag) / scale)
    return bool(np.all(np.abs(dz) / scale <= ROUNDOFF_BAND * EPS * size[which]))


def newton(residual, jacobian, z0, scale, tol, max_iter, factor=None, rate_refresh=RATE_REFRESH,
           chord_iterations=5, polish=0, offset=None):
    """Solve residual(z) = 0 from z0.

    Parameters
    ----------
    residual : callable z -> r
    jacobian : callable z -> sparse matrix
    scale : ndarray
        Typical magnitude of each unknown; convergence is ``max|dz/scale| <= tol``,
        or the update has reached round-off: ``<= 8 eps max|z/scale|``; or it stagnates
        below ``100 tol`` with a fresh Jacobian; or it stops contracting (an update between half
        and ``MAX_ROUNDOFF_RATE`` times the previous one, after a contracting one) with every
        component within ``ROUNDOFF_BAND`` of the round-off floor of its kind,
        ``eps max((|z| + |offset|) / scale)`` over the unknowns sharing its scale.  A chord iteration contracts
        at a steady rate, so an update that suddenly stops shrinking that close to the floor is
        round-off, not a stale Jacobian: no refactorisation is spent on it.  Divergence (updates
        growing three times in a row) is still reported, whatever their size.
    factor : object, optional
        A factorisation from an earlier call, reused until the rate degrades.
    rate_refresh : float
        Contraction rate above which the Jacobian is refreshed: low when a Jacobian is cheap
        relative to a residual (the tube's sparse Hessian), higher when it is dear (the rod's
        banded differences cost ~40 residuals).
    chord_iterations : int
        Iterations allowed on an inherited Jacobian before it is refreshed regardless of rate.
    polish : int
        Extra iterations allowed *after* ``tol`` is met, taken while each update is still clearly
        smaller than the previous one (i.e. until the round-off floor).  The error left in a step's momentum
        balance is the final residual, and it accumulates over a long run; polishing makes it
        round-off instead of tolerance-sized, at the cost of a few residuals (no Jacobian).
    offset : ndarray, optional
        Where the unknowns are displacements, the absolute values the residual evaluates
        (``offset + z``, e.g. label positions along the tube): its round-off is relative to
        those, so the update cannot get below ``~eps |offset + z|``.  Default: zero.
    """
    z = np.array(z0, dtype=np.float64, copy=True)
    mag = np.zeros_like(z) if offset is None else np.abs(np.asarray(offset, dtype=np.float64))
    n_res = n_jac = 0
    jac_iter = None  # iteration at which the factorisation in use was computed (None: inherited)
    if factor is None:
        J = jacobian(z)
        factor = factorize(J)
        n_jac += 1
        jac_iter = 0
        if factor is None:
            return NewtonResult(False, z, 0, np.inf, np.nan, None, n_res, n_jac, _singular(J))
    err_prev = None
    rate = np.nan
    rate_prev = np.nan  # the contraction rate of the previous update on this factorisation
    it = 0
    err = np.inf
    n_growing = 0  # consecutive growing updates
    polished = 0
    while it < max_iter + polished:
        r = residual(z)
        n_res += 1
        if not np.all(np.isfinite(r)):
            return NewtonResult(False, z, it, np.inf, rate, factor, n_res, n_jac, "residual is not finite")
        dz = -factor.solve(r)
        z += dz
        it += 1
        err = float(np.max(np.abs(dz) / scale)) if len(z) else 0.0
        floor = 8 * EPS * (float(np.max(np.abs(z) / scale)) if len(z) else 1.0)
        if err <= tol or err <= floor:
            contracting = polished == 0 or err < 0.7 * err_prev
            if polished < polish and err > floor and contracting:
                polished += 1
                err_prev = err
                continue
            return NewtonResult(True, z, it, err, rate, factor, n_res, n_jac)
        if polished:  # a polishing update that grew past tol: round-off noise, keep the converged point
            z -= dz
            return NewtonResult(True, z, it, err_prev, rate, factor, n_res, n_jac, "polished to round-off")
        if err_prev is not None:
            rate = err / err_prev
            slow_inherited = jac_iter is None and it >= chord_iterations  # an old Jacobian needing many iterations
            if not np.isfinite(rate) or rate > rate_refresh or slow_inherited:
                recent = jac_iter is not None and jac_iter >= it - 2
                # each kind of unknown (those sharing a scale: labels, radii, multipliers) against the
                # floor of its own kind; one global floor would let a radius beside 10^5 labels stop at
                # the labels' floor, far above its own
                at_floor = _within_floor(dz, z, mag, scale)
                if recent and err <= 100 * tol:
                    # stagnating just above tol with an up-to-date Jacobian: round-off of an ill-conditioned system
                    return NewtonResult(True, z, it, err, rate, factor, n_res, n_jac, "stagnated at round-off")
                if STAGNATION_RATE <= rate < MAX_ROUNDOFF_RATE and at_floor and rate_prev <= rate_refresh:
                    # the chord was contracting and the update stopped shrinking near the floor of the
                    # state's round-off: the state cannot resolve a smaller update, a new Jacobian would not help
                    return NewtonResult(True, z, it, err, rate, factor, n_res, n_jac, "stopped at the round-off floor")
                growing = not np.isfinite(rate) or rate >= 1.0
                n_growing = n_growing + 1 if growing else 0
                if n_growing >= 3:
                    return NewtonResult(False, z, it, err, rate, factor, n_res, n_jac, "diverging")
                if jac_iter is None or jac_iter < it:
                    # slow contraction: refresh the Jacobian here and carry on
                    J = jacobian(z)
                    factor = factorize(J)
                    n_jac += 1
                    jac_iter = it
                    err_prev = None
                    rate_prev = np.nan
                    if factor is None:
                        return NewtonResult(False, z, it, err, rate, None, n_res, n_jac, _singular(J))
                    continue
            rate_prev = rate
        err_prev = err
    return NewtonResult(False, z, it, err, rate, factor, n_res, n_jac, "no convergence within max_iterations")


def newton_damped(residual, jacobian, z0, scale, tol, max_iter, weight=None):
    """Full Newton with a fresh Jacobian every iteration and backtracking on ||weight * r||.

    The fallback when the chord iteration of :func:`newton` fails from a poor predictor (stiff
    modes that the midpoint rule flips every step, large rotations).  ``weight`` makes the
    residual norm dimensionally consistent (default: ``scale``).
    """
    w = scale if weight is None else weight
    z = np.array(z0, dtype=np.float64, copy=True)
    r = residual(z)
    n_res, n_jac = 1, 0
    norm = float(np.linalg.norm(w * r))
    factor = None
    err = np.inf
    for it in range(1, max_iter + 1):
        if not np.isfinite(norm):
            return NewtonResult(False, z, it, np.inf, np.nan, factor, n_res, n_jac, "residual is not finite")
        J = jacobian(z)
        factor = factorize(J)
        n_jac += 1
        if factor is None:
            return NewtonResult(False, z, it, err, np.nan, None, n_res, n_jac, _singular(J))
        dz = -factor.solve(r)
        alpha = 1.0
        while True:
            zt = z + alpha * dz
            rt = residual(zt)
            n_res += 1
            nt = float(np.linalg.norm(w * rt))
            if (np.isfinite(nt) and nt <= (1 - 1e-4 * alpha) * norm) or alpha < 1.0 / 256:
                break
            alpha *= 0.5
        stalled = not nt < (1 - 1e-4) * norm
        z, r, norm = zt, rt, nt
        err = float(np.max(np.abs(alpha * dz) / scale))
        if alpha == 1.0 and (err <= tol or err <= 8 * EPS * float(np.max(np.abs(z) / scale))):
            return NewtonResult(True, z, it, err, np.nan, factor, n_res, n_jac, "damped Newton")
        if stalled and err <= 100 * tol:
            # a fresh Jacobian and no decrease of the residual: the round-off floor of the system
            return NewtonResult(True, z, it, err, np.nan, factor, n_res, n_jac, "damped Newton")
    return NewtonResult(False, z, max_iter, err, np.nan, factor, n_res, n_jac, "damped Newton did not converge")
