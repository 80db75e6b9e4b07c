"""Classical linear stability of pipes conveying fluid: an independent truth.

This module does not use varint's model or stepper. It solves the classical
dimensionless Euler-Bernoulli equation of a pipe conveying fluid (plug flow,
Benjamin 1961; Gregory & Païdoussis 1966; Païdoussis, *Fluid-Structure
Interactions* vol. 1 (1998), ch. 3, eq. (3.70) without tension, pressurisation
and damping)::

    η'''' + [u² − γ(1 − ξ)] η'' + 2 β^{1/2} u ∂²η/∂ξ∂τ + γ η' + ∂²η/∂τ² = 0,

on ξ = x/L ∈ [0, 1], with

* u = U L sqrt(M/EI)                (dimensionless flow velocity),
* β = M/(M + m)                      (mass ratio; M fluid, m pipe mass per length),
* τ = t sqrt(EI/(M + m)) / L²        (dimensionless time),
* γ = (M + m) g L³ / EI              (gravity; γ > 0 hanging: the clamped end
  is above the free end, γ < 0 standing).

Gravity is a steady tension γ(1 − ξ) (zero at the free end) and is meant for the
cantilever. Ends (``ends``): ``"clamped-free"`` (cantilever; free end
η'' = η''' = 0, the standard result for the discharge of a free jet),
``"pinned-pinned"``, ``"clamped-clamped"``.

Motions are η ∝ exp(iωτ): a complex frequency ω is damped for Im ω > 0 and grows
for Im ω < 0; flutter when Im ω crosses 0 with Re ω ≠ 0, divergence when ω = 0.

Two independent methods:

``method="galerkin"``
    Galerkin with the N beam eigenfunctions of the same ends (Païdoussis §3.3.6(b));
    the integrals b_sr = ∫φ_s φ_r', c_sr = ∫φ_s φ_r'', d_sr = ∫φ_s (1 − ξ) φ_r''
    by Gauss-Legendre quadrature on numerically stable closed forms of the beam
    functions; the 2N eigenvalues of the first-order system.
``method="exact"``
    The exact characteristic determinant (Païdoussis §3.3.6(a)): for a trial ω the
    ODE  Y'''' + [u² − γ(1−ξ)]Y'' + (2iωβ^{1/2}u + γ)Y' − ω²Y = 0  is integrated
    exactly (γ = 0: one matrix exponential of the companion matrix; γ ≠ 0: a
    fourth-order Magnus product, A(ξ) being linear in ξ), and the 2×2 minor of the
    transfer matrix picked by the boundary conditions vanishes at an eigenvalue.
    Eigenvalues are followed from the beam's (u = 0) by Newton's method along u;
    thresholds are refined with scipy's ``brentq``.

The dimensional helpers convert a tube (EI, M, m, L, U, g) to (u, β, γ) and back.
"""

import numpy as np
from scipy import linalg, optimize

from ..errors import VarintError

__all__ = [
    "ENDS",
    "beam_wavenumbers",
    "beam_function",
    "galerkin_matrices",
    "eigenvalues",
    "characteristic_determinant",
    "exact_eigenvalue",
    "critical_flow_velocity",
    "dimensionless_parameters",
    "flow_velocity",
    "dimensionless_flow_velocity",
    "frequency_hz",
]

ENDS = ("clamped-free", "pinned-pinned", "clamped-clamped")
_ALIASES = {"cantilever": "clamped-free", "cantilevered": "clamped-free"}


def _ends(ends):
    e = _ALIASES.get(ends, ends)
    if e not in ENDS:
        raise VarintError(f"pipe_stability: ends must be one of {', '.join(ENDS)}, got {ends!r}")
    return e


def _check_beta(beta):
    if not (0.0 <= beta <= 1.0):
        raise VarintError(f"pipe_stability: beta = M/(M+m) must be in [0, 1], got {beta!r}")


# ----------------------------------------------------------------------------------------
# Beam eigenfunctions
# ----------------------------------------------------------------------------------------

def beam_wavenumbers(ends, n):
    """The first n roots λ_r of the beam's frequency equation (ω_r = λ_r² at u = 0).

    clamped-free: cos λ cosh λ = −1; clamped-clamped: cos λ cosh λ = 1;
    pinned-pinned: λ_r = rπ. Roots by ``brentq`` on the stable forms
    cos λ ± 1/cosh λ.
    """
    ends = _ends(ends)
    r = np.arange(1, n + 1)
    if ends == "pinned-pinned":
        return r * np.pi
    sign = 1.0 if ends == "clamped-free" else -1.0

    def f(lam):
        return np.cos(lam) + sign / np.cosh(lam)

    lams = []
    for k in r:
        centre = (k - 0.5) * np.pi if ends == "clamped-free" else (k + 0.5) * np.pi
        lams.append(optimize.brentq(f, centre - 0.5 * np.pi + 1e-9, centre + 0.5 * np.pi - 1e-9,
                                    xtol=1e-15, rtol=1e-15, maxiter=200))
    return np.array(lams)


def _sigma_parts(ends, lam):
    """σ_r and 1 − σ_r computed without cancellation (1 − σ ~ e^{−λ})."""
    if ends == "clamped-free":
        den = np.cosh(lam) + np.cos(lam)
        sigma = (np.sinh(lam) - np.sin(lam)) / den
        one_minus = (np.exp(-lam) + np.cos(lam) + np.sin(lam)) / den
    else:  # clamped-clamped
        den = np.sinh(lam) - np.sin(lam)
        sigma = (np.cosh(lam) - np.cos(lam)) / den
        one_minus = (-np.exp(-lam) + np.cos(lam) - np.sin(lam)) / den
    return sigma, one_minus


def beam_function(ends, lam, xi, k=0):
    """k-th derivative (k = 0..4) of the beam eigenfunction of wavenumber ``lam`` at ``xi``.

    clamped ends: φ = cosh λξ − cos λξ − σ (sinh λξ − sin λξ) (normalised ∫φ² = 1),
    evaluated as ((1−σ)/2) e^{λξ} + ((1+σ)/2) e^{−λξ} − cos λξ + σ sin λξ;
    pinned-pinned: φ = √2 sin λξ.
    """
    ends = _ends(ends)
    xi = np.asarray(xi, dtype=float)
    x = lam * xi
    phase = 0.5 * np.pi * k
    if ends == "pinned-pinned":
        return np.sqrt(2.0) * lam**k * np.sin(x + phase)
    sigma, one_minus = _sigma_parts(ends, lam)
    a, b = 0.5 * one_minus, 0.5 * (1.0 + sigma)
    val = a * np.exp(x) + (-1) ** k * b * np.exp(-x) - np.cos(x + phase) + sigma * np.sin(x + phase)
    return lam**k * val


def galerkin_matrices(ends, n_modes, n_quad=None):
    """Beam wavenumbers λ and the Galerkin integrals (B, C, D), each n×n.

    B_sr = ∫φ_s φ_r',  C_sr = ∫φ_s φ_r'',  D_sr = ∫φ_s (1 − ξ) φ_r''  over [0, 1],
    by Gauss-Legendre quadrature (exact to round-off for the default n_quad).
    """
    ends = _ends(ends)
    lam = beam_wavenumbers(ends, n_modes)
    if n_quad is None:
        n_quad = max(200, 8 * n_modes)
    x, w = np.polynomial.legendre.leggauss(n_quad)
    xi, w = 0.5 * (x + 1.0), 0.5 * w
    phi = np.array([beam_function(ends, l, xi, 0) for l in lam])
    dphi = np.array([beam_function(ends, l, xi, 1) for l in lam])
    d2phi = np.array([beam_function(ends, l, xi, 2) for l in lam])
    norm = np.sqrt((phi**2) @ w)
    phi, dphi, d2phi = (a / norm[:, None] for a in (phi, dphi, d2phi))
    B = (phi * w) @ dphi.T
    C = (phi * w) @ d2phi.T
    D = (phi * w * (1.0 - xi)) @ d2phi.T
    return lam, B, C, D


def eigenvalues(u, beta, ends, gamma=0.0, n_modes=40, all=False):
    """Dimensionless complex frequencies ω (η ∝ e^{iωτ}) by the Galerkin method.

    Returns the eigenvalues with Re ω ≥ 0 (the others are −conj of these), sorted by
    Re ω (then Im ω); purely imaginary ones (overdamped or divergent motions) appear
    with both signs of Im ω as they come. With ``all=True`` all 2N eigenvalues.
    Only the lower half or so of the N modes are converged.
    Instability: Im ω < 0 for some ω.
    """
    _check_beta(beta)
    lam, B, C, D = _galerkin_cached(_ends(ends), int(n_modes))
    return _galerkin_eigs(lam, B, C, D, u, beta, gamma, all)


_GALERKIN_CACHE = {}


def _galerkin_cached(ends, n):
    key = (ends, n)
    if key not in _GALERKIN_CACHE:
        _GALERKIN_CACHE[key] = galerkin_matrices(ends, n)
    return _GALERKIN_CACHE[key]


def _stiffness(lam, B, C, D, u, gamma):
    return np.diag(lam**4) + u * u * C + gamma * (B - D)


def _galerkin_eigs(lam, B, C, D, u, beta, gamma, all=False):
    n = len(lam)
    K = _stiffness(lam, B, C, D, u, gamma)
    G = 2.0 * np.sqrt(beta) * u * B
    A = np.zeros((2 * n, 2 * n))
    A[:n, n:] = np.eye(n)
    A[n:, :n] = -K
    A[n:, n:] = -G
    s = linalg.eigvals(A)          # q ∝ e^{sτ}, s = iω
    om = -1j * s
    if not all:
        scale = np.maximum(1.0, np.abs(om))
        om = om[om.real >= -1e-9 * scale]
    return om[np.lexsort((om.imag, om.real))]


# ----------------------------------------------------------------------------------------
# Exact characteristic determinant
# ----------------------------------------------------------------------------------------

_LEFT = {"clamped": (2, 3), "pinned": (1, 3)}     # free unknowns of (Y, Y', Y'', Y''') at ξ = 0
_RIGHT = {"clamped": (0, 1), "pinned": (0, 2), "free": (2, 3)}  # conditions at ξ = 1


def _companion(omega, u, beta, gamma, xi):
    """Companion matrices A(ξ) (..., 4, 4) of y' = A y, y = (Y, Y', Y'', Y''')."""
    omega = np.asarray(omega, dtype=complex)
    xi = np.asarray(xi, dtype=float)
    shape = np.broadcast_shapes(omega.shape, xi.shape)
    A = np.zeros(shape + (4, 4), dtype=complex)
    A[..., 0, 1] = A[..., 1, 2] = A[..., 2, 3] = 1.0
    A[..., 3, 0] = omega**2
    A[..., 3, 1] = -(2j * omega * np.sqrt(beta) * u + gamma)
    A[..., 3, 2] = -(u * u - gamma * (1.0 - xi))
    return A


def _expm(A):
    """exp of a batch of small matrices (..., n, n): scaling and squaring with a
    degree-18 Taylor polynomial (truncation < 1e-20 after scaling to norm <= 1/2).
    Vectorised over the batch (scipy.linalg.expm loops over it)."""
    norm = np.max(np.sum(np.abs(A), axis=-1), axis=-1)
    nmax = float(np.max(norm)) if norm.size else 0.0
    s = max(0, int(np.ceil(np.log2(nmax))) + 1) if nmax > 0 else 0
    X = A / 2.0**s
    eye = np.broadcast_to(np.eye(A.shape[-1], dtype=A.dtype), A.shape)
    E = eye + X / 18.0
    for k in range(17, 0, -1):
        E = eye + (X @ E) / k
    for _ in range(s):
        E = E @ E
    return E


def _transfer(omega, u, beta, gamma, n_steps):
    """Transfer matrices T(ω) with y(1) = T y(0) for an array of ω (shape (..., 4, 4))."""
    omega = np.asarray(omega, dtype=complex)
    if gamma == 0.0:
        return _expm(_companion(omega, u, beta, 0.0, 0.0))
    # fourth-order Magnus (two Gauss points) on n_steps equal intervals
    h = 1.0 / n_steps
    c = 0.5 - np.sqrt(3.0) / 6.0, 0.5 + np.sqrt(3.0) / 6.0
    left = np.arange(n_steps) * h
    om = omega[..., None]
    A1 = _companion(om, u, beta, gamma, left + c[0] * h)
    A2 = _companion(om, u, beta, gamma, left + c[1] * h)
    Om = 0.5 * h * (A1 + A2) + (np.sqrt(3.0) / 12.0) * h * h * (A2 @ A1 - A1 @ A2)
    E = _expm(Om)                      # (..., n_steps, 4, 4), E[k] maps ξ_k to ξ_{k+1}
    while E.shape[-3] > 1:             # ordered product E[n-1] ... E[1] E[0], pairwise
        if E.shape[-3] % 2:
            eye = np.broadcast_to(np.eye(4, dtype=complex), E.shape[:-3] + (1, 4, 4))
            E = np.concatenate([E, eye], axis=-3)
        E = E[..., 1::2, :, :] @ E[..., 0::2, :, :]
    return E[..., 0, :, :]


def _bc(ends):
    left, right = _ends(ends).split("-")
    return _LEFT[left], _RIGHT[right]


def characteristic_determinant(omega, u, beta, ends, gamma=0.0, n_steps=200):
    """The exact characteristic function D(ω; u) (array in ω): zero at an eigenvalue.

    D is the 2×2 minor of the transfer matrix (rows: the conditions at ξ = 1,
    columns: the unknowns at ξ = 0); analytic in ω and u. ``n_steps`` is used only
    for γ ≠ 0 (Magnus steps; error ∝ n_steps⁻⁴).
    """
    cols, rows = _bc(ends)
    T = _transfer(omega, u, beta, float(gamma), n_steps)
    M = T[..., rows, :][..., :, cols]
    return M[..., 0, 0] * M[..., 1, 1] - M[..., 0, 1] * M[..., 1, 0]


def _newton(f, z0, tol=1e-12, maxiter=40):
    """Complex Newton iteration on a vectorised analytic f with central differences.

    Converged when every step is below ``tol`` (relative); a step that stagnates
    at round-off (D is evaluated to about eps·e^{2λ}) is accepted below 1e-9."""
    z = np.array(z0, dtype=complex)
    dz = np.full(z.shape, np.inf)
    for _ in range(maxiter):
        h = 1e-6 * np.maximum(1.0, np.abs(z))
        f0, fp, fm = f(np.stack([z, z + h, z - h]))
        df = (fp - fm) / (2 * h)
        dz = np.where(df != 0, f0 / np.where(df != 0, df, 1.0), 0.0)
        z = z - dz
        if np.all(np.abs(dz) <= tol * np.maximum(1.0, np.abs(z))):
            return z, True
    return z, bool(np.all(np.abs(dz) <= 1e-9 * np.maximum(1.0, np.abs(z))))


def exact_eigenvalue(omega0, u, beta, ends, gamma=0.0, n_steps=200, strict=True):
    """An exact eigenvalue ω of the pipe near ``omega0`` (Newton on D(ω)).

    ``strict=False`` returns the last iterate when Newton did not converge to 1e-9
    (a double root, where Newton is only linear)."""
    _check_beta(beta)
    f = lambda z: characteristic_determinant(z, u, beta, ends, gamma, n_steps)  # noqa: E731
    with np.errstate(all="ignore"):
        z, ok = _newton(f, np.atleast_1d(omega0), maxiter=40 if strict else 200)
    if not ok and strict:
        raise VarintError(f"pipe_stability: Newton on the characteristic determinant did not "
                          f"converge near omega = {omega0} at u = {u}")
    return z[0] if np.ndim(omega0) == 0 else z


def _divergence_exact(u_max, beta, ends, gamma, n_steps, du=0.05):
    """First u in (0, u_max] where ω = 0 is an eigenvalue (D(0; u) real, changes sign)."""
    f = lambda u: characteristic_determinant(0.0, u, beta, ends, gamma, n_steps).real  # noqa: E731
    us = np.arange(du, u_max + du, du)
    vals = [f(u) for u in us]
    for k in range(len(us) - 1):
        if vals[k] == 0.0:
            return us[k]
        if np.sign(vals[k]) != np.sign(vals[k + 1]):
            return optimize.brentq(f, us[k], us[k + 1], xtol=1e-14, rtol=1e-15)
    return None


def _contour_count(u, beta, ends, gamma, n_steps, W, H, max_points=200_000):
    """Number of exact eigenvalues in the rectangle 0 < Re ω < W, −H < Im ω < −ε
    (growing, oscillating motions) by the argument principle, and a sum-of-roots seed.

    The phase of D(ω; u) is followed around the rectangle, segments being halved until
    every phase step is below π/4. ε = 1e-6 keeps the contour off the real axis, where
    the eigenvalues of conservative (supported) pipes lie. Returns (count, sum of the
    roots inside).
    """
    eps = 1e-6
    corners = [-1j * H, W - 1j * H, W - 1j * eps, -1j * eps, -1j * H]   # counter-clockwise
    n_edge = [max(64, int(W)), 64, max(256, 4 * int(W)), 64]
    z = np.concatenate([np.linspace(corners[k], corners[k + 1], n_edge[k], endpoint=False)
                        for k in range(4)] + [np.array([corners[0]])])
    with np.errstate(all="ignore"):
        d = characteristic_determinant(z, u, beta, ends, gamma, n_steps)
    while True:
        step = np.angle(d[1:] / d[:-1])
        refine = np.flatnonzero(np.abs(step) > np.pi / 4)
        if refine.size == 0:
            break
        if z.size + refine.size > max_points:
            raise VarintError(f"pipe_stability: the argument-principle contour at u = {u:.6g} "
                              f"needs more than {max_points} points (a root on the contour?)")
        zm = 0.5 * (z[refine] + z[refine + 1])
        with np.errstate(all="ignore"):
            dm = characteristic_determinant(zm, u, beta, ends, gamma, n_steps)
        z = np.insert(z, refine + 1, zm)
        d = np.insert(d, refine + 1, dm)
    step = np.angle(d[1:] / d[:-1])
    count = int(np.rint(np.sum(step) / (2 * np.pi)))
    dlog = np.log(np.abs(d[1:] / d[:-1])) + 1j * step
    root_sum = np.sum(0.5 * (z[1:] + z[:-1]) * dlog) / (2j * np.pi)
    return count, root_sum


def _flutter_exact(u_stop, beta, ends, gamma, n_steps, du, W, H):
    """First flutter crossing of the exact eigenvalues, found without any mode tracking:
    the count of growing oscillating eigenvalues (argument principle) on a grid in u,
    the bracket halved until one eigenvalue is inside, that eigenvalue located (contour
    moment, then Newton) and followed back in u by ``brentq`` on Im ω(u)."""
    us = np.arange(du, u_stop, du)
    ua = 0.0
    for ub in us:
        n, rsum = _contour_count(ub, beta, ends, gamma, n_steps, W, H)
        if n > 0:
            break
        ua = ub
    else:
        return None
    if ua == 0.0:
        ua = 0.5 * ub
    # halve the bracket until exactly one growing eigenvalue at ub
    while n != 1 or ub - ua > du / 8:
        um = 0.5 * (ua + ub)
        nm, rm = _contour_count(um, beta, ends, gamma, n_steps, W, H)
        if nm > 0:
            ub, n, rsum = um, nm, rm
        else:
            ua = um
        if ub - ua < 1e-10:
            break
    ob = exact_eigenvalue(rsum, ub, beta, ends, gamma, n_steps)
    # follow that eigenvalue back to ua in small steps (Newton from the previous one)
    path = [(ub, ob)]
    for t in np.linspace(1.0, 0.0, 9)[1:]:
        uu = ua + t * (ub - ua)
        path.append((uu, exact_eigenvalue(path[-1][1], uu, beta, ends, gamma, n_steps,
                                          strict=False)))
    path = path[::-1]
    oa = path[0][1]
    tiny = 1e-10
    if oa.imag < -tiny:
        raise VarintError(f"pipe_stability: the exact eigenvalue near u = {ua:.6g} did not "
                          f"return to stability (beta = {beta}, {ends})")
    k = next(i for i, (_, o) in enumerate(path) if o.imag < -tiny)
    return path[k - 1][0], path[k][0], path[k - 1][1], path[k][1]


def _refine_flutter_exact(ua, ub, oa, ob, beta, ends, gamma, n_steps):
    """brentq on Im ω(u) of one followed eigenvalue between ua (stable) and ub (unstable)."""
    state = {"u": ua, "om": oa}

    def im_om(u):
        # predict linearly between the bracketing values, then Newton
        t = (u - ua) / (ub - ua)
        z = exact_eigenvalue(oa + t * (ob - oa), u, beta, ends, gamma, n_steps, strict=False)
        state["u"], state["om"] = u, z
        return z.imag + 1e-10     # as in the Galerkin scan: also brackets a coalescence

    uc = optimize.brentq(im_om, ua, ub, xtol=1e-13, rtol=1e-15)
    return uc, exact_eigenvalue(state["om"], uc, beta, ends, gamma, n_steps, strict=False)


# ----------------------------------------------------------------------------------------
# Thresholds
# ----------------------------------------------------------------------------------------

def _divergence_galerkin(u_max, lam, B, C, D, gamma, du):
    """First u where det K(u) = 0 (ω = 0 an eigenvalue of the Galerkin system)."""
    def f(u):
        K = _stiffness(lam, B, C, D, u, gamma)
        sign, logdet = np.linalg.slogdet(K / lam[:, None] ** 4)
        return sign * np.exp(min(logdet, 50.0))

    us = np.arange(du, u_max + du, du)
    prev = f(0.0)
    for k, u in enumerate(us):
        cur = f(u)
        if np.sign(cur) != np.sign(prev):
            a = us[k - 1] if k > 0 else 0.0
            return optimize.brentq(f, a, u, xtol=1e-14, rtol=1e-15)
        prev = cur
    return None


def critical_flow_velocity(beta, ends, gamma=0.0, method="galerkin", n_modes=40,
                           u_max=30.0, du=0.05, n_steps=200, flutter_tol=1e-8,
                           omega_box=(150.0, 60.0)):
    """The first loss of stability of the straight pipe as u grows from 0.

    Returns ``(u_c, omega_c, kind)``: the dimensionless critical flow velocity, the
    (real) dimensionless frequency ω_c = Re ω of the mode that loses stability
    (0 for divergence), and ``kind`` = ``"divergence"`` or ``"flutter"``.
    Returns ``(None, None, None)`` if the pipe stays stable up to ``u_max``.

    method ``"galerkin"``: N = ``n_modes`` beam modes; divergence where det K(u) = 0,
    flutter where the smallest Im ω over the eigenvalues with Re ω ≠ 0 first
    crosses 0 (scan with step ``du``, then ``brentq``).
    method ``"exact"``: divergence where the exact determinant D(0; u) = 0; flutter
    where the number of exact eigenvalues in the box 0 < Re ω < ``omega_box[0]``,
    −``omega_box[1]`` < Im ω < 0 (argument principle on D) first becomes positive on
    the grid of step ``du``; that eigenvalue is then followed back by Newton and the
    crossing Im ω = 0 found by ``brentq``. No Galerkin input, no mode labels.

    A window of instability narrower than ``du`` (the S-shaped parts of the
    cantilever's curve, near β ≈ 0.30, 0.69, 0.92) can be missed by both methods;
    reduce ``du`` there.
    """
    _check_beta(beta)
    ends = _ends(ends)
    gamma = float(gamma)
    if method == "galerkin":
        lam, B, C, D = _galerkin_cached(ends, int(n_modes))
        u_div = _divergence_galerkin(u_max, lam, B, C, D, gamma, du)
        u_stop = u_div if u_div is not None else u_max

        def g(u):
            om = _galerkin_eigs(lam, B, C, D, u, beta, gamma)
            scale = np.maximum(1.0, np.abs(om))
            osc = om[np.abs(om.real) > 1e-6 * scale]
            return np.min(osc.imag / np.maximum(1.0, np.abs(osc))) if osc.size else np.inf

        us = np.arange(du, u_stop, du)
        u_fl = None
        prev_u = 0.0
        for u in us:
            if g(u) < -flutter_tol:
                if prev_u == 0.0:
                    prev_u = 0.5 * u
                # root of min Im ω = −tol: brackets also a coalescence of real
                # frequencies (β = 0), where Im ω is 0 up to round-off before it
                u_fl = optimize.brentq(lambda v: g(v) + flutter_tol, prev_u, u,
                                       xtol=1e-13, rtol=1e-15)
                break
            prev_u = u
        if u_fl is not None and (u_div is None or u_fl < u_div):
            om = _galerkin_eigs(lam, B, C, D, u_fl, beta, gamma)
            osc = om[np.abs(om.real) > 1e-6 * np.maximum(1.0, np.abs(om))]
            j = np.argmin(osc.imag / np.maximum(1.0, np.abs(osc)))   # the one that crossed
            return u_fl, float(osc[j].real), "flutter"
        if u_div is not None:
            return u_div, 0.0, "divergence"
        return None, None, None
    if method == "exact":
        u_div = _divergence_exact(u_max, beta, ends, gamma, n_steps, du=du)
        # stop short of a divergence: there ω = 0 is a double root (a flutter within
        # 0.1 % below a divergence would be missed; supported ends are conservative
        # gyroscopic systems, which do not flutter before they diverge)
        u_stop = u_div * (1.0 - 1e-3) if u_div is not None else u_max
        hit = _flutter_exact(u_stop, beta, ends, gamma, n_steps, du, omega_box[0], omega_box[1])
        if hit is not None:
            uc, omc = _refine_flutter_exact(*hit, beta, ends, gamma, n_steps)
            return uc, float(omc.real), "flutter"
        if u_div is not None:
            return u_div, 0.0, "divergence"
        return None, None, None
    raise VarintError(f"pipe_stability: method must be 'galerkin' or 'exact', got {method!r}")


# ----------------------------------------------------------------------------------------
# Dimensional helpers
# ----------------------------------------------------------------------------------------

def dimensionless_parameters(EI, M, m, L, U=0.0, g=0.0):
    """(u, β, γ, t_ref) of a tube: bending stiffness EI [N m²], fluid mass per length M
    [kg/m], pipe mass per length m [kg/m], length L [m], flow speed U [m/s], gravity g
    [m/s²] (> 0 hanging). Dimensional time t = τ t_ref, t_ref = L² sqrt((M+m)/EI)."""
    for name, val in (("EI", EI), ("L", L), ("M + m", M + m)):
        if not val > 0:
            raise VarintError(f"pipe_stability: {name} must be > 0, got {val!r}")
    if M < 0 or m < 0:
        raise VarintError(f"pipe_stability: masses per length must be >= 0, got M={M!r}, m={m!r}")
    u = U * L * np.sqrt(M / EI)
    beta = M / (M + m)
    gamma = (M + m) * g * L**3 / EI
    t_ref = L * L * np.sqrt((M + m) / EI)
    return u, beta, gamma, t_ref


def dimensionless_flow_velocity(U, EI, M, L):
    """u = U L sqrt(M/EI)."""
    return U * L * np.sqrt(M / EI)


def flow_velocity(u, EI, M, L):
    """The flow speed U [m/s] of a dimensionless u: U = u sqrt(EI/M) / L."""
    return u * np.sqrt(EI / M) / L


def frequency_hz(omega, EI, M, m, L):
    """The frequency [Hz] of a dimensionless ω: Ω = ω sqrt(EI/(M+m)) / L², f = Ω/2π."""
    return np.real(omega) * np.sqrt(EI / (M + m)) / (L * L) / (2.0 * np.pi)
