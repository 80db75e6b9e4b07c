"""Linear analysis: normal modes of the discrete model and the analytic dispersion relation.

:func:`modes` linearises the *discrete* Lagrangian about a configuration: the
stiffness is the Hessian of the potential in the unknowns, the mass the
lumped diagonal M; algebraic unknowns (quasistatic wall, pressure multipliers)
are condensed statically.  :func:`dispersion_branches` is the continuum
relation derived in docs/theory.md §6; it is independent of the lattice.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from .errors import VarintError

__all__ = ["linearization", "modes", "modes_of", "gyroscopic_modes_of", "sparse_modes_of", "sparse_gyroscopic_modes_of", "dispersion_branches", "webster_frequencies", "euler_bernoulli_cantilever",
           "timoshenko_cantilever", "elastica_cantilever_tip", "spinning_shaft_whirl", "flowing_pipe_waves",
           "flowing_pipe_critical_speed", "peak_growth_rate"]


def _tube(model):
    """The tube part of a model (its s, R, mu blocks); a part is accepted as it is."""
    return model.tube if hasattr(model, "tube") else model


def linearization(model, z=None):
    """Mass (nq,) and condensed stiffness (nq, nq) of the tube's blocks, dense, about z (default: the
    initial state)."""
    model = _tube(model)
    if z is None:
        z = np.concatenate([model.q_init, model.lam_init])
    H = model.hessian(model.config(z))
    K = (model.B.T @ H @ model.B).toarray() if sp.issparse(H) else model.B.T @ H @ model.B
    nq = model.nq
    Kqq = K[:nq, :nq]
    if model.nlam:
        Kql, Kll = K[:nq, nq:], K[nq:, nq:]
        Kqq = Kqq - Kql @ np.linalg.solve(Kll, Kql.T)
    return model.mass.copy(), 0.5 * (Kqq + Kqq.T)


#: above this many inertial unknowns the tube's modes come from a sparse shift-invert solver
DENSE_TUBE_MODES_LIMIT = 3000


def modes(model, count=20, z=None, vectors=False, method="auto"):
    """Lowest eigenfrequencies of the linearised model.

    Returns a list of ``{"frequency": omega [rad/s], "growth_rate": sigma [1/s]}``
    sorted by frequency (an unstable mode has frequency 0 and sigma > 0);
    with ``vectors`` the mode shapes (nq, count) are returned too.  ``method``: "dense", "sparse"
    (shift-invert Lanczos for the lowest ``count``; models without algebraic unknowns) or "auto"
    (sparse above :data:`DENSE_TUBE_MODES_LIMIT` inertial unknowns when possible).  Rods: see
    :func:`varint.rod_statics.rod_modes`.
    """
    model = _tube(model)
    sparse = method == "sparse" or (method == "auto" and model.nq > DENSE_TUBE_MODES_LIMIT)
    if sparse and model.nlam:
        if model.nq > 6000:
            raise VarintError("modes: with algebraic unknowns (quasistatic wall or incompressible fluid) the modes "
                              "use the dense eigen-solver, limited to 6000 inertial unknowns")
        sparse = False
    if sparse:
        if z is None:
            z = np.concatenate([model.q_init, model.lam_init])
        H = sp.csr_matrix(model.hessian(model.config(z)))
        K = (model.B.T @ H @ model.B).tocsc()
        return sparse_modes_of(0.5 * (K + K.T), model.mass.copy(), count, vectors)
    M, K = linearization(model, z)
    return modes_of(K, M, count, vectors)


def modes_of(K, M, count, vectors=False):
    """Generalised eigenproblem K x = w^2 diag(M) x -> modes list (and shapes), in eigenvalue order.

    A negative eigenvalue is an instability (frequency 0, growth rate sqrt(-w^2)) unless it is
    round-off small: below 1e-14 of the largest |w^2| (rigid-body modes of a free rod sit at
    ~1e-17 of it, the eigen-solver's round-off: the same with the exact element Hessian as with the
    finite differences of 0.1; a column at 1.1 x its Euler load at ~2e-13).  Eigenvalue order lists instabilities first, then frequencies increasing.
    """
    w2, X = sla.eigh(K, np.diag(M))
    res = _modes_from_w2(w2[:count], 1e-14 * max(abs(w2[-1]), abs(w2[0]), 1e-300))
    return (res, X[:, :count]) if vectors else res


def _modes_from_w2(w2, floor):
    """w^2 -> {"frequency", "growth_rate"}: a negative w^2 beyond the round-off ``floor`` is a growth rate."""
    return [{"frequency": math.sqrt(max(lam, 0.0)), "growth_rate": 0.0} if lam >= -floor
            else {"frequency": 0.0, "growth_rate": math.sqrt(-lam)} for lam in w2]


def _arpack(solver, *args, **kw):
    """Call a scipy ARPACK solver; its failures become one-line errors."""
    import scipy.sparse.linalg as spla

    try:
        return solver(*args, **kw)
    except (spla.ArpackNoConvergence, RuntimeError) as exc:
        raise VarintError(f"modes: the sparse eigen-solver (ARPACK) failed ({str(exc).splitlines()[0]}); "
                          "ask for fewer modes (-n)") from None


def gyroscopic_modes_of(K, G, M, count, vectors=False):
    """Modes of M q'' + G q' + K q = 0 (G skew: gyroscopic; diag(M)) -> modes list (and shapes).

    The first-order form x' = A x, x = (q, q'), has a Hamiltonian spectrum: eigenvalues come as
    +-lam (and conjugates).  Each degree of freedom is reported once: an oscillation +-i w as
    frequency w; a real pair +-s as frequency 0, growth rate s; a flutter quadruple +-a +- i w as two
    entries (w, |a|).  Zero eigenvalues (rigid motions, Jordan blocks) are those below 1e-7 of the
    largest |lam|: their round-off splitting is ~sqrt(eps); for the same reason real and imaginary
    parts below that are reported as 0 (the threshold of :func:`modes_of`, 1e-14 on w^2).  Sorted
    by frequency, then growth rate descending; with ``vectors`` the complex displacement parts of
    the mode shapes too.
    """
    n = len(M)
    A = np.zeros((2 * n, 2 * n))
    A[:n, n:] = np.eye(n)
    A[n:, :n] = -K / M[:, None]
    A[n:, n:] = -G / M[:, None]
    lam, X = sla.eig(A)
    return _one_per_degree_of_freedom(lam, X[:n], 1e-7 * max(np.max(np.abs(lam)), 1e-300), count, vectors, complete=True)


def _one_per_degree_of_freedom(lam, X, tiny, count, vectors, complete):
    """Select one eigenvalue per degree of freedom from a Hamiltonian spectrum (see above).

    ``complete``: ``lam`` is the whole spectrum, so half of a cluster of zeros is one per degree of
    freedom; otherwise (a partial, shift-inverted spectrum) every zero found is kept and paired by
    the order it comes in.  ``tiny``: magnitudes (and real or imaginary parts) below it are round-off.
    """
    zero = np.abs(lam) <= tiny
    keep = ~zero & ((lam.imag > tiny) | ((np.abs(lam.imag) <= tiny) & (lam.real > 0)))
    zeros = np.flatnonzero(zero)
    picks = list(np.flatnonzero(keep)) + list(zeros[: (len(zeros) + (0 if complete else 1)) // 2])
    res = []
    for i in picks:
        real_pair = abs(lam[i].imag) <= tiny and not zero[i]
        res.append({"frequency": 0.0 if zero[i] or real_pair else float(lam[i].imag),
                    "growth_rate": 0.0 if zero[i] or abs(lam[i].real) <= tiny else float(abs(lam[i].real))})
    order = sorted(range(len(res)), key=lambda k: (res[k]["frequency"], -res[k]["growth_rate"]))
    res = [res[k] for k in order][:count]
    if vectors:
        return res, X[:, [picks[k] for k in order][:count]]
    return res


def highest_frequency_estimate(K, M):
    """max_i sqrt(sum_j |K_ij| / M_i): a Gershgorin bound on the largest frequency (sparse or dense K)."""
    rows = np.asarray(abs(K).sum(axis=1)).ravel()
    return float(np.sqrt(np.max(rows / M)))


#: shifts of the shift-invert Lanczos solver, -shift x (Gershgorin bound on w^2), tried in turn: just
#: below zero, so that rigid modes (K singular) are found with the lowest oscillations.  1e-8 keeps
#: ARPACK accurate beside rigid modes (at 1e-14 their huge inverted eigenvalues cost a free rod's
#: elastic pair 2e-4); a slender rod's lowest w^2 is ~1e-15 of the bound at L/r = 10^4, where 1e-8
#: does not converge and 1e-14 does (the rigid modes' round-off, ~1e-19 of the bound, stays below it).
SPARSE_SHIFTS = (1e-8, 1e-14)


def sparse_modes_of(K, M, count, vectors=False):
    """The lowest ``count`` modes of K x = w^2 diag(M) x by shift-invert Lanczos (scipy eigsh).

    For models too large for the dense solver.  The shift sits just below zero (:data:`SPARSE_SHIFTS` of
    the largest w^2, estimated by :func:`highest_frequency_estimate`), so rigid modes and instabilities are found
    with the lowest oscillations; classification as in :func:`modes_of`.
    """
    import scipy.sparse.linalg as spla

    K = sp.csc_matrix(K)
    big2 = highest_frequency_estimate(K, M) ** 2  # a bound, often well above the true highest w^2
    k = min(count, K.shape[0] - 2)
    # a fixed start vector: ARPACK's default is random, and results must not change between runs
    for i, shift in enumerate(SPARSE_SHIFTS):
        try:
            # (shift-invert converges in tens of restarts when it converges: the first shift gets 300)
            w2, X = _arpack(spla.eigsh, K, k=k, M=sp.diags(M).tocsc(), sigma=-shift * big2, which="LM",
                            v0=np.ones(K.shape[0]), maxiter=300 if i < len(SPARSE_SHIFTS) - 1 else None)
            break
        except VarintError:
            if i == len(SPARSE_SHIFTS) - 1:
                raise
    order = np.argsort(w2)
    w2, X = w2[order], X[:, order]
    # eigenvalues near the shift come out with small absolute error: a threshold of 1e-9 of the
    # bound on the frequency (1e-18 on w^2), where the dense solver needs 1e-7
    res = _modes_from_w2(w2, 1e-18 * big2)
    return (res, X) if vectors else res


def sparse_gyroscopic_modes_of(K, G, M, count, vectors=False):
    """The lowest ``count`` modes of M q'' + G q' + K q = 0 by shift-invert Arnoldi (scipy eigs) on the
    first-order form, shifted by 1e-4 of the estimated highest frequency; classification as in
    :func:`gyroscopic_modes_of` with round-off below 1e-9 of that (Gershgorin, so generous) estimate.
    For models too large for the dense solver."""
    import scipy.sparse.linalg as spla

    n = len(M)
    Minv = sp.diags(1.0 / M)
    A = sp.bmat([[None, sp.identity(n)], [-(Minv @ sp.csr_matrix(K)), -(Minv @ sp.csr_matrix(G))]]).tocsc()
    big = highest_frequency_estimate(K, M)
    k = min(2 * count + 4, 2 * n - 2)
    lam, X = _arpack(spla.eigs, A, k=k, sigma=1e-4 * big, which="LM", v0=np.ones(2 * n))
    return _one_per_degree_of_freedom(lam, X[:n], 1e-9 * big, count, vectors, complete=False)


def dispersion_branches(k, c0, rho0, R0, a, beta1, beta2):
    """Angular frequencies (low, high) of small waves exp(i(ks - wt)) in the expandable tube.

    From docs/theory.md §6:  (a/c0^2) w^4 - [(b/c0^2) + 4 pi rho0 + a k^2] w^2 + k^2 b = 0,
    b = beta2 + beta1 k^2, about rest at p = p_ext and R = R0.  ``c0`` is the sound
    speed of the fluid (math.inf for an incompressible liquid).  With a = 0 only
    the low (acoustic/Moens-Korteweg) branch exists and ``high`` is nan.
    """
    k = np.asarray(k, dtype=float)
    b = beta2 + beta1 * k * k
    inv_c2 = 0.0 if math.isinf(c0) else 1.0 / c0 ** 2
    B = b * inv_c2 + 4 * math.pi * rho0 + a * k * k
    C = k * k * b
    A = a * inv_c2
    if A == 0.0:
        return np.sqrt(C / B), np.full_like(k, np.nan)
    disc = np.sqrt(B * B - 4 * A * C)
    # the small root without cancellation
    lo = 2 * C / (B + disc)
    hi = (B + disc) / (2 * A)
    return np.sqrt(lo), np.sqrt(hi)


def webster_frequencies(area, L, c, count, omega_max=None):
    """Closed-closed acoustic frequencies of Webster's horn equation (A p')' + (w/c)^2 A p = 0.

    Shooting with scipy's ``solve_ivp`` from p(0) = 1, p'(0) = 0; roots of p'(L)
    in w bracketed on a fine grid and refined with ``brentq``.  Independent of
    the varint lattice: ``area`` is any callable A(s).
    """
    from scipy.integrate import solve_ivp
    from scipy.optimize import brentq

    def end_slope(w):
        def rhs(s, y):  # y = (p, A p')
            return [y[1] / area(s), -(w / c) ** 2 * area(s) * y[0]]

        sol = solve_ivp(rhs, (0.0, L), [1.0, 0.0], rtol=1e-12, atol=1e-14, method="DOP853")
        return sol.y[1, -1]

    omega_max = omega_max or (count + 1.5) * math.pi * c / L
    grid = np.linspace(1e-6, omega_max, 40 * (count + 2))
    vals = [end_slope(w) for w in grid]
    roots = []
    for (w0, f0), (w1, f1) in zip(zip(grid, vals), zip(grid[1:], vals[1:])):
        if f0 == 0 or f0 * f1 < 0:
            roots.append(brentq(end_slope, w0, w1, xtol=1e-13, rtol=1e-14))
        if len(roots) == count:
            break
    return np.array(roots)


# ---------------------------------------------------------------------------
# classical beam results, solved independently of the lattice (for validation)

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


def peak_growth_rate(t, y, skip=1):
    """Growth rate [1/time] of an oscillation from the peaks of |y(t)|: the slope of a least-squares line through
    log |y| at the peaks, leaving out the first ``skip`` (a kick's transient).  Positive: growing.  Raises
    ValueError with fewer than three peaks to fit."""
    a = np.abs(np.asarray(y, dtype=float))
    t = np.asarray(t, dtype=float)
    pk = [i for i in range(1, len(a) - 1) if a[i] >= a[i - 1] and a[i] > a[i + 1]][skip:]
    if len(pk) < 3:
        raise ValueError(f"too few peaks ({len(pk)} after skipping {skip}) to fit a growth rate")
    return float(np.polyfit(t[pk], np.log(a[pk]), 1)[0])
