"""Measuring a captured shock in a run file: the jumps across it and their Rankine-Hugoniot residuals.

:func:`measure_shock` for the straight tube, :func:`measure_coupled_shock` for a bent, moving tube (a run of the
coupled model); the jump conditions are the paper's (``RH_mass``, ``RH_momentum``, ``RH_energy``), from
:mod:`varint.exact.shocks`.
"""

from __future__ import annotations

import math

import numpy as np

from ..exact.shocks import ShockError, ideal_gas_state, relative_residuals, rh_residuals
from ..run.io import read_run
from ..terms.coupled import element_strains

__all__ = ["measure_shock", "measure_coupled_shock", "density_l1"]


def density_l1(s, rho, exact, t, samples=100001):
    """L1 distance on [0, 1] between the parcels' piecewise-constant density (``rho`` on the parcels between the
    labels ``s``) and the exact one at time ``t`` (a :class:`varint.exact.shocks.RiemannSolution`, diaphragm at 0.5),
    integrated on ``samples`` - 1 equal sub-intervals."""
    x = np.linspace(0.0, 1.0, samples)
    xc = 0.5 * (x[1:] + x[:-1])
    k = np.clip(np.searchsorted(s, xc) - 1, 0, len(rho) - 1)
    return float(np.sum(np.abs(rho[k] - exact.sample(xc, t, 0.5)[0])) * (x[1] - x[0]))


def _crossing(s_centres, p, i, level):
    """Position where p crosses ``level`` between parcel centres i and i+1 (linear interpolation)."""
    a, b = p[i], p[i + 1]
    t = 0.5 if b == a else min(max((level - a) / (b - a), 0.0), 1.0)
    return s_centres[i] + t * (s_centres[i + 1] - s_centres[i])


def _steepest_jump(F, k, window, path):
    """(i, parcel centres, pressures) of record k: i the neighbouring parcels (i, i+1) with the largest pressure jump
    (inside ``window`` = (s_min, s_max) when given)."""
    s = F["fluid/s"][k]
    p = F["fluid/pressure"][k]
    c = 0.5 * (s[:-1] + s[1:])
    dp = np.abs(np.diff(p))
    if window is not None:
        dp = np.where((c[:-1] >= window[0]) & (c[1:] <= window[1]), dp, -1.0)
    i = int(np.argmax(dp))
    if dp[i] <= 0:
        raise ShockError(f"{path}: no pressure jump found in record {k}")
    return i, c, p


def _shock_sides(F, n, window, path, offset):
    """The steepest jump of record n and the parcels ``offset`` either side of it: (i, centres, pressures, il, ir,
    level), level the mean of the two sides' pressures (the shock's position is where p crosses it)."""
    i, c, p = _steepest_jump(F, n, window, path)
    il, ir = i - offset, i + 1 + offset
    if il < 0 or ir >= len(p):
        raise ShockError(f"{path}: the shock at parcel {i} is closer than {offset} parcels to an end")
    return i, c, p, il, ir, 0.5 * (p[il] + p[ir])


def _level_crossing(c, p, i, level):
    """Where the pressure crosses ``level`` at the jump between parcels i, i + 1 (at the jump's mid-pressure if the
    level is outside it)."""
    inside = min(p[i], p[i + 1]) <= level <= max(p[i], p[i + 1])
    return _crossing(c, p, i, level if inside else 0.5 * (p[i] + p[i + 1]))


def _shock_position(F, k, level, window, path):
    """Where record k's pressure crosses ``level`` at its steepest jump."""
    i, c, p = _steepest_jump(F, k, window, path)
    return _level_crossing(c, p, i, level)


def measure_shock(path, record=-1, offset=4, window=None, gamma=None):
    """Jumps across the captured shock of one record of a run file, and their Rankine–Hugoniot residuals.

    The shock is the steepest pressure jump between neighbouring parcels (searched in ``window = (s_a, s_b)``
    when given); the states either side are the parcels ``offset`` parcels away from it (velocity: the
    mean of the parcel's two labels; radius: the wall interpolated at the parcel centre, or none on a
    rigid tube).  The speed is that of the point where the pressure crosses the mean of the two states,
    from the previous record to this one.  The jump conditions are ``RH_mass``, ``RH_momentum``,
    ``RH_energy`` for the straight tube (``Gamma = E1``, ``gam = 0``; ``Q = pi R^2``).  ``gamma``: the
    gas's ratio of specific heats (default: read from the scene stored in the file).

    Returns ``{"position", "speed", "left", "right", "jumps", "residuals", "relative"}``: the jumps of
    rho, u, p, R, and the residuals (absolute and relative to the size of the jumps, see
    :func:`rh_residuals`).
    """
    run = read_run(path)
    F = run["fields"]
    for need in ("fluid/s", "fluid/density", "fluid/pressure", "fluid/velocity"):
        if need not in F:
            raise ShockError(f"{path}: no field {need} (a fluid run with the fluid fields written is needed)")
    K = len(run["time"])
    n = record % K if K else 0
    if K < 2 or n < 1:
        raise ShockError(f"{path}: measuring a shock's speed needs a record after the first (file has {K})")
    if gamma is None:
        import tomllib
        text = run["attrs"].get("scene_toml", "")
        try:
            gamma = float(tomllib.loads(text).get("fluid", {}).get("gamma", 1.4))
        except tomllib.TOMLDecodeError:
            gamma = 1.4
    t = run["time"]

    i, c, p, il, ir, level = _shock_sides(F, n, window, path, offset)
    x1 = _crossing(c, p, i, level)
    x0 = _shock_position(F, n - 1, level, window, path)
    speed = (x1 - x0) / (t[n] - t[n - 1])
    u_lab = F["fluid/velocity"][n]
    u = 0.5 * (u_lab[:-1] + u_lab[1:])
    rho = F["fluid/density"][n]
    R = None
    if "wall/R" in F:
        Rn = F["wall/R"][n]
        L = F["fluid/s"][n][-1] - F["fluid/s"][n][0]
        node_s = F["fluid/s"][n][0] + np.linspace(0.0, L, len(Rn))
        R = np.interp(c, node_s, Rn)

    def state(k):
        return ideal_gas_state(rho[k], u[k], p[k], gamma, R=None if R is None else R[k])

    left, right = state(il), state(ir)
    res = rh_residuals(left, right, speed)
    jumps = {"rho": right.rho - left.rho, "u": right.u - left.u, "p": right.p - left.p}
    if R is not None:
        jumps["R"] = float(R[ir] - R[il])
    return {"position": float(x1), "speed": float(speed), "time": float(t[n]), "left": left, "right": right,
            "jumps": jumps, "residuals": {k: res[k] for k in ("mass", "momentum", "energy")},
            "relative": relative_residuals(res)}


def measure_coupled_shock(path, record=None, offset=4, window=None, gamma=None, span=None, average=None):
    """Jumps across the captured shock of one record of a coupled run file (a gas on a [rod]), and
    their generalised Rankine–Hugoniot residuals (``RH_mass``, ``RH_momentum``, ``RH_energy``) in the tube's
    convected frame (docs/theory.md §11a, "In the coupled tube").  A rigid tube or a dynamic wall; closed ends.

    The record (default: the file's middle one) must have records on either side, the run written every step
    around it: the rates are centred differences between records ``n - 1`` and ``n + 1``; the shock's speed is
    the slope at record n of a least-squares parabola (a line below 5 records) through its positions in records
    ``n - span`` to ``n + span`` (default: as many records as there are on both sides; a captured shock's
    crossing point moves in jerks as it passes parcel after parcel, so the speed needs a longer baseline than
    the rates).  The shock is the steepest pressure jump between
    neighbouring parcels (in ``window = (s_a, s_b)`` of the reference coordinate when given); each side's state is
    the parcel ``offset`` parcels away, at its centre c (reference arclength):

    * ``rho``, ``p`` the parcel's (``e = p / ((gamma - 1) rho)``); ``u`` = ds/dt, the paper's u (the fluid's
      velocity in the body frame is gam + Gamma u), the mean over the parcel's two labels of their centred rates;
    * ``Gamma``, ``gam`` the tube's, at the shock (the same on both sides: the tube is smooth across the shock):
      the lattice strain Lambda_hat_e^T (r_{e+1} - r_e)/ds of the element holding the shock and
      Lambda_hat_e^T r_dot there, r_dot the nodes' centred rates interpolated linearly (Lambda_hat_e the
      element's mean frame, the one that defines Gamma_e); ``Q = pi R^2 |Gamma|`` with R the tube's radius, a
      wall's interpolated at the shock (``wall/R``);
    * the speed c = ds_shock/dt of the point where the pressure crosses the mean of the two states.

    Each side's (rho, u, p, Gamma, gam) is the mean over the records n - average .. n + average (default
    ``span - 1``; 0: record n alone), each read ``offset`` parcels from that record's own shock: the captured
    shock rings at the parcel scale behind it, and a single snapshot's states carry that noise into the residuals.

    Returns the dictionary of :func:`measure_shock` (``position``, ``speed``, ``time``, ``left``, ``right``,
    ``jumps``, ``residuals``, ``relative``) plus ``classical_relative``: the straight-tube conditions of the same
    (rho, u, p) (Gamma = E1, gam = 0), for comparison.
    """
    import tomllib

    run = read_run(path)
    F = run["fields"]
    for need in ("fluid/s", "fluid/density", "fluid/pressure", "rod/r", "rod/Lambda"):
        if need not in F:
            raise ShockError(f"{path}: no field {need} (a coupled run with the fluid and rod fields written is needed)")
    t = run["time"]
    K = len(t)
    n = (K // 2 if record is None else record % K) if K else 0
    if not 1 <= n <= K - 2:
        raise ShockError(f"{path}: record {n} needs a record on either side (file has {K})")
    span = min(n, K - 1 - n) if span is None else int(span)
    if not 1 <= span <= min(n, K - 1 - n):
        raise ShockError(f"{path}: span {span} reaches beyond the records around record {n} (file has {K})")
    try:
        sc = tomllib.loads(run["attrs"].get("scene_toml", ""))
    except tomllib.TOMLDecodeError:
        sc = {}
    tube = sc.get("tube", {})
    if "radius" not in tube or "length" not in tube or "nodes" not in tube:
        raise ShockError(f"{path}: the stored scene has no tube.length, tube.radius and tube.nodes")
    if sc.get("rod", {}).get("ends", {}).get("s0") == "periodic":
        raise ShockError(f"{path}: periodic coupled tubes are not measured in this version")
    gamma = float(sc.get("fluid", {}).get("gamma", 1.4)) if gamma is None else gamma
    R0, ds = float(tube["radius"]), float(tube["length"]) / (int(tube["nodes"]) - 1)

    level = _shock_sides(F, n, window, path, offset)[-1]
    xs = [_shock_position(F, k, level, window, path) for k in range(n - span, n + span + 1)]
    # least squares through the crossings: a line, or a parabola (the shock may accelerate) from 5 records on
    tt = t[n - span:n + span + 1] - t[n]
    speed = float(np.polyfit(tt, xs, 2 if len(xs) >= 5 else 1)[-2])
    G_ = {}

    def sides(k):
        """(left, right) of record k as parameter vectors (rho, u, p, Gamma (3), gam (3)), offset parcels either
        side of that record's steepest jump; the rates are centred on records k - 1, k + 1."""
        try:
            ik, ck, pk, a, b, _ = _shock_sides(F, k, window, path, offset)
        except ShockError as exc:
            raise ShockError(f"{exc} (record {k})") from None
        dt = t[k + 1] - t[k - 1]
        u_lab = (F["fluid/s"][k + 1] - F["fluid/s"][k - 1]) / dt
        r, Lam = F["rod/r"][k], F["rod/Lambda"][k]
        G = element_strains(Lam, r, ds)[0]
        rdot = (F["rod/r"][k + 1] - F["rod/r"][k - 1]) / dt
        N = len(r) - 1
        # the tube's strain and velocity at the shock itself (the tube is smooth across it: the conditions take
        # one Gamma, gam for both sides; read at the fluid states, offset parcels away, they would carry the tube's
        # own gradients, e.g. a stretching tube's d gam/ds, into the residuals)
        xk = _level_crossing(ck, pk, ik, level)
        e = min(max(int(math.floor(xk / ds)), 0), N - 1)
        tau = xk / ds - e
        Lhat = 0.5 * (Lam[e] + Lam[e + 1])
        gam = Lhat.T @ ((1.0 - tau) * rdot[e] + tau * rdot[e + 1])
        # a wall's radius, at the shock too (the wall is continuous across it; nodes at s_j = j ds)
        Rk = np.interp(xk, ds * np.arange(N + 1), F["wall/R"][k]) if "wall/R" in F else R0
        return [np.concatenate([[F["fluid/density"][k][j], 0.5 * (u_lab[j] + u_lab[j + 1]), pk[j]], G[e], gam, [Rk]])
                for j in (a, b)]

    # each side's state, averaged over the records n - span + 1 .. n + span - 1 (each read about its own shock
    # position; the captured shock's ringing is a parcel-scale oscillation that this averages out)
    avg = span - 1 if average is None else int(average)
    if not 0 <= avg <= span - 1:
        raise ShockError(f"{path}: average {avg} must lie in 0 .. span - 1 = {span - 1}")
    both = np.array([sides(k) for k in range(n - avg, n + avg + 1)]).mean(axis=0)

    def state(x, straight=False):
        if straight:
            return ideal_gas_state(x[0], x[1], x[2], gamma, R=x[9])
        return ideal_gas_state(x[0], x[1], x[2], gamma, R=x[9], Gamma=x[3:6], gam=x[6:9])

    left, right = state(both[0]), state(both[1])
    res = rh_residuals(left, right, speed)
    jumps = {"rho": right.rho - left.rho, "u": right.u - left.u, "p": right.p - left.p}
    classical = relative_residuals(rh_residuals(state(both[0], True), state(both[1], True), speed))
    return {"position": float(xs[span]), "speed": float(speed), "time": float(t[n]), "left": left,
            "right": right, "jumps": jumps, "residuals": {k: res[k] for k in ("mass", "momentum", "energy")},
            "relative": relative_residuals(res), "classical_relative": classical, "records_averaged": 2 * avg + 1}
