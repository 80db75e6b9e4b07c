"""Closed-form and ODE-accurate truths for beams and pipes: the outside results the rod and the flowing tube are
validated against (docs/validation.md).  Independent of the lattice and of the stepper.

* :func:`euler_bernoulli_cantilever`, :func:`timoshenko_cantilever`: the cantilever's bending frequencies
  (Euler-Bernoulli; Timoshenko with shear and rotary inertia).
* :func:`elastica_cantilever_tip`: the tip of a cantilever under a dead tip load (the elastica, by collocation).
* :func:`spinning_shaft_whirl`: forward and backward whirl of a spinning Timoshenko shaft.
* :func:`flowing_pipe_waves`, :func:`flowing_pipe_critical_speed`: waves on an infinite Timoshenko pipe conveying
  fluid and the speed where they turn unstable.
* :func:`spinning_free_rod_flap`: the flap frequencies of a free rod spun about its transverse axis.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["EULER_BERNOULLI_CLAMPED_FREE", "euler_bernoulli_cantilever", "timoshenko_cantilever",
           "elastica_cantilever_tip", "spinning_shaft_whirl", "flowing_pipe_waves", "flowing_pipe_critical_speed",
           "spinning_free_rod_flap"]


EULER_BERNOULLI_CLAMPED_FREE = (1.8751040687119611, 4.6940911329741745, 7.8547574382376126, 10.995540734875467)


def euler_bernoulli_cantilever(EI, rhoA, L, count=3):
    """omega_n = (beta_n L)^2 sqrt(EI / (rhoA L^4)) of a clamped-free Euler-Bernoulli beam."""
    return np.array([b * b * math.sqrt(EI / (rhoA * L ** 4)) for b in EULER_BERNOULLI_CLAMPED_FREE[:count]])


def timoshenko_cantilever(EI, kGA, rhoA, rhoI, L, count=3):
    """Clamped-free Timoshenko frequencies by shooting (scipy solve_ivp + brentq).

    -w^2 rhoA W = kGA (W'' - P'),  -w^2 rhoI P = EI P'' + kGA (W' - P);
    W = P = 0 at s = 0, kGA (W' - P) = EI P' = 0 at s = L.
    """
    from scipy.integrate import solve_ivp
    from scipy.optimize import brentq

    def det(w):
        def rhs(s, y):
            W, P, dW, dP = y
            return [dW, dP, dP - w * w * rhoA * W / kGA, (-w * w * rhoI * P - kGA * (dW - P)) / EI]

        cols = []
        for y0 in ([0, 0, 1, 0], [0, 0, 0, 1]):
            y = solve_ivp(rhs, (0, L), y0, rtol=1e-12, atol=1e-14, method="DOP853").y[:, -1]
            cols.append([kGA * (y[2] - y[1]), EI * y[3]])
        return cols[0][0] * cols[1][1] - cols[0][1] * cols[1][0]

    guesses = euler_bernoulli_cantilever(EI, rhoA, L, count + 1)
    grid = np.linspace(0.3 * guesses[0], 1.05 * guesses[count - 1] + 0.5 * (guesses[count] - guesses[count - 1]), 400 * count)
    vals = [det(w) for w in grid]
    roots = []
    for (a, fa), (b, fb) in zip(zip(grid, vals), zip(grid[1:], vals[1:])):
        if fa * fb < 0:
            roots.append(brentq(det, a, b, xtol=1e-12, rtol=1e-14))
        if len(roots) == count:
            break
    return np.array(roots)


def elastica_cantilever_tip(load, EI, L):
    """Inextensible elastica of a cantilever (clamped at s = 0 along +x) under a dead tip load -load*E_y.

    theta'' = -(load/EI) cos(theta), theta(0) = 0, theta'(L) = 0, solved with scipy's solve_bvp.
    Returns (x_tip, y_tip, theta_tip).
    """
    from scipy.integrate import solve_bvp

    k = load / EI
    s = np.linspace(0.0, L, 401)

    def f(s, y):  # y = (theta, theta', x, y)
        return np.vstack([y[1], -k * np.cos(y[0]), np.cos(y[0]), np.sin(y[0])])

    def bc(ya, yb):
        return np.array([ya[0], yb[1], ya[2], ya[3]])

    guess = np.zeros((4, s.size))
    guess[2] = s
    # continuation in the load keeps solve_bvp on the physical (downward) branch
    sol = None
    for frac in np.linspace(0.1, 1.0, 10):
        k = frac * load / EI
        sol = solve_bvp(f, bc, s, guess if sol is None else sol.sol(s), tol=1e-10, max_nodes=100000)
        if not sol.success:
            raise RuntimeError(sol.message)
    th, _, x, y = sol.sol(L)
    # theta measured from +x towards -y for a downward load
    return x, -y, -th if th > 0 else th


def spinning_shaft_whirl(k, rhoA, rhoI, rhoJp, EI, kGA, spin):
    """Whirl frequencies (forward, backward) in rad/s, seen from the ground, of a simply supported
    Timoshenko shaft spinning at ``spin`` about its axis, in the mode sin(k x) (lowest, bending branch).

    With u = v + i w the complex lateral displacement and psi the complex section rotation, the
    linearised equations (docs/theory.md §9, "Modes of a spinning rod") for u = U sin(kx) e^{i w t},
    psi = Psi cos(kx) e^{i w t} are

        (kGA k^2 - rhoA w^2) U - kGA k Psi = 0,
        -kGA k U + (EI k^2 + kGA - rhoI w^2 + s rhoJp spin w) Psi = 0,

    s = +1 for the forward whirl (w > 0 in the sense of the spin: gyroscopic stiffening), s = -1 the
    backward one.  Rayleigh limit (kGA -> inf): (rhoA + rhoI k^2) w^2 -+ rhoJp spin k^2 w - EI k^4 = 0.
    The quartic's positive roots are found by numpy; the lowest is the bending branch.
    """
    out = []
    for s in (1.0, -1.0):
        a = np.array([-rhoA, 0.0, kGA * k * k])
        c = np.array([-rhoI, s * rhoJp * spin, EI * k * k + kGA])
        det = np.polysub(np.polymul(a, c), [(kGA * k) ** 2])
        roots = np.roots(det)
        pos = sorted(float(x.real) for x in roots if abs(x.imag) <= 1e-9 * abs(x) and x.real > 0)
        out.append(pos[0])
    return tuple(out)


def flowing_pipe_waves(k, U, EI, kGA, rhoA, rhoI, M):
    """The two bending-branch frequencies (complex, rad/s) of lateral waves w = W exp(i (k x - omega t)) on an
    infinite straight Timoshenko pipe conveying a plug flow of speed ``U`` and mass ``M`` per length (rhoA: the
    pipe's; rhoI: its rotary inertia; the fluid follows the centreline, Païdoussis vol. 1 §3.2, with shear):

        (rhoA + M) w_tt + 2 M U w_xt + M U^2 w_xx - kGA (w_xx - psi_x) = 0,
        rhoI psi_tt - EI psi_xx - kGA (w_x - psi) = 0.

    Inserting the wave: [-(rhoA+M) om^2 + 2 M U k om - M U^2 k^2 + kGA k^2] (EI k^2 + kGA - rhoI om^2)
    - kGA^2 k^2 = 0, a quartic whose two roots of least modulus are the bending branch (the others, near
    sqrt(kGA / rhoI), the shear branch).  Sorted by real part.  The Euler–Bernoulli limit (kGA -> inf,
    rhoI -> 0), -(rhoA+M) om^2 + 2 M U k om + EI k^4 - M U^2 k^2 = 0, has complex roots (one growing,
    Im om > 0) above U^2 = (rhoA + M) EI k^2 / (rhoA M): the periodic pipe is stabilised by the Coriolis force
    past the divergence speed U^2 = EI k^2 / M of the pinned pipe and loses stability by coupled-mode flutter.
    ``M`` is the fluid mass per reference length (rho_f A); the centrifugal term acts on the centreline slope
    w_x, not on the frame angle psi (the fluid follows the centreline).  The relation is linear and holds for a
    closed periodic loop too (Kelvin's circulation in place of a pumped U gives the same quadratic form,
    docs/theory.md §10.11); a closed loop with a stiff wall leaves the linear range early, the pressure drop of
    the lengthened loop acting as a tension (ibid.).
    """
    p1 = np.array([-(rhoA + M), 2.0 * M * U * k, kGA * k * k - M * U * U * k * k])
    p2 = np.array([-rhoI, 0.0, EI * k * k + kGA])
    roots = np.roots(np.polysub(np.polymul(p1, p2), [kGA * kGA * k * k]))
    low = sorted(roots, key=abs)[:2]
    return tuple(sorted((complex(w) for w in low), key=lambda w: w.real))


def flowing_pipe_critical_speed(k, EI, kGA, rhoA, rhoI, M, U_max=None):
    """The flow speed U_c at which the two bending waves of :func:`flowing_pipe_waves` meet and one starts to grow
    (coupled-mode flutter of the periodic pipe), by bisection on their imaginary parts between 0 and ``U_max``
    (default: 4 times the Euler–Bernoulli U_c = k sqrt((rhoA + M) EI / (rhoA M)))."""
    def grows(U):
        return max(abs(w.imag) for w in flowing_pipe_waves(k, U, EI, kGA, rhoA, rhoI, M)) > 1e-9 * k * k * math.sqrt(EI / (rhoA + M))

    hi = U_max if U_max is not None else 4.0 * k * math.sqrt((rhoA + M) * EI / (rhoA * M))
    if not grows(hi):
        raise ValueError(f"flowing_pipe_critical_speed: the waves do not grow below U_max = {hi:g}")
    lo = 0.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if not grows(mid) else (lo, mid)
        if hi - lo <= 1e-13 * hi:
            break
    return 0.5 * (lo + hi)


def spinning_free_rod_flap(EI, rhoA, L, spin, omega_max, samples=400):
    """Out-of-plane ("flap") frequencies, in the spinning frame, of a free Euler-Bernoulli rod spun end
    over end at ``spin`` about a transverse axis through its centre: all roots in (0, omega_max].

    The centrifugal tension N(x) = rhoA spin^2 (l^2 - x^2) / 2 (x from the centre, l = L/2) stiffens
    the bending; displacements normal to the plane of rotation feel neither Coriolis nor centrifugal
    force, so  rhoA w_tt - (N w_x)_x + EI w_xxxx = 0.  With m = EI w'' and Q = m' - N w' this is
    w' = theta, theta' = m/EI, m' = Q + N theta, Q' = rhoA omega^2 w, free at x = l (m = Q = 0);
    symmetric modes have theta = Q = 0 at the centre, antisymmetric ones w = m = 0.  Shooting
    (scipy solve_ivp) and brentq on the 2x2 end determinant.  The rigid tilt appears at omega = spin.
    (In the plane of rotation the same tension acts, plus -rhoA spin^2 w: omega_lag^2 = omega_flap^2 - spin^2
    when the Coriolis coupling with the stiff axial motion is neglected.)
    """
    from scipy.integrate import solve_ivp
    from scipy.optimize import brentq

    ell = 0.5 * L

    def ends(omega, starts):
        def rhs(x, y):
            N = 0.5 * rhoA * spin * spin * (ell * ell - x * x)
            w, th, m, Q = y
            return [th, m / EI, Q + N * th, rhoA * omega * omega * w]

        cols = [solve_ivp(rhs, (0.0, ell), y0, rtol=1e-11, atol=1e-14).y[:, -1] for y0 in starts]
        return cols[0][2] * cols[1][3] - cols[1][2] * cols[0][3]

    roots = []
    for starts in (([1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]), ([0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0])):
        grid = np.linspace(omega_max / samples, omega_max, samples)
        vals = [ends(w, starts) for w in grid]
        for a, b, fa, fb in zip(grid, grid[1:], vals, vals[1:]):
            if fa == 0.0 or fa * fb < 0:
                roots.append(brentq(lambda w: ends(w, starts), a, b, xtol=1e-13, rtol=1e-13))
    return sorted(roots)
