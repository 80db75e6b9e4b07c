"""The classical linear stability of pipes conveying fluid (varint/exact/pipe_stability.py).

Every test compares with a truth from outside the module's own methods: closed-form
beam frequencies and divergence velocities, the Bessel-function buckling of a standing
cantilever, published thresholds (Païdoussis, Fluid-Structure Interactions vol. 1,
1998, §3.5 and Table 3.4), or the agreement of the two independent methods (Galerkin
with beam functions; exact characteristic determinant with the argument principle).
"""

import numpy as np
import pytest
from scipy import optimize, special

from varint.exact import pipe_stability as ps
from varint.errors import VarintError

# u = 0: Euler-Bernoulli beam frequencies ω_r = λ_r² (Blevins, Formulas for natural
# frequency and mode shape, Table 8-1: λ₁ = 1.87510, 4.69409 (clamped-free);
# 4.73004, 7.85320 (clamped-clamped); π, 2π (pinned-pinned)).
BEAM = {
    "clamped-free": (1.87510407**2, 4.69409113**2),      # 3.5160, 22.0345
    "pinned-pinned": (np.pi**2, 4 * np.pi**2),
    "clamped-clamped": (4.73004074**2, 7.85320462**2),   # 22.3733, 61.6728
}


@pytest.mark.parametrize("ends", ps.ENDS)
def test_zero_flow_gives_the_beam_frequencies(ends):
    truth = np.array(BEAM[ends])
    om = ps.eigenvalues(0.0, 0.3, ends)[:2]
    assert np.allclose(om.real, truth, rtol=1e-7) and np.allclose(om.imag, 0.0, atol=1e-8)
    ex = [ps.exact_eigenvalue(0.9 * w, 0.0, 0.3, ends) for w in truth]
    assert np.allclose(ex, truth, rtol=1e-8)   # the constants above have 9 digits


@pytest.mark.parametrize("ends, truth", [("pinned-pinned", np.pi), ("clamped-clamped", 2 * np.pi)])
def test_supported_pipes_diverge_at_pi_and_two_pi(ends, truth):
    # classical (Païdoussis §3.4.1): u_cd = π and 2π, independent of β
    for beta in (0.1, 0.5, 0.9):
        u, om, kind = ps.critical_flow_velocity(beta, ends, du=0.1)
        assert kind == "divergence" and om == 0.0
        assert abs(u - truth) < 1e-6
    for beta in (0.2, 0.8):
        u, om, kind = ps.critical_flow_velocity(beta, ends, method="exact", du=0.2)
        assert kind == "divergence" and abs(u - truth) < 1e-9
    # just below: all frequencies real (neutrally stable); just above: a growing root
    below = ps.eigenvalues(0.99 * truth, 0.5, ends)
    above = ps.eigenvalues(1.01 * truth, 0.5, ends)
    assert np.min(below.imag) > -1e-8 and np.min(above.imag) < -1e-2


@pytest.mark.parametrize("beta", [0.1, 0.2, 0.5, 0.8])
def test_cantilever_flutter_two_methods_agree(beta):
    ug, wg, kg = ps.critical_flow_velocity(beta, "clamped-free", du=0.1)
    ue, we, ke = ps.critical_flow_velocity(beta, "clamped-free", method="exact", du=0.2)
    assert kg == ke == "flutter"
    assert abs(ug - ue) < 1e-4 and abs(wg - we) < 1e-3 * we
    # the exact threshold is a real eigenvalue of the exact determinant at u_c
    assert abs(ps.exact_eigenvalue(we, ue, beta, "clamped-free").imag) < 1e-8
    # 0.93 u_c all damped, 1.07 u_c one growing mode at about ω_c
    lo = ps.eigenvalues(0.93 * ue, beta, "clamped-free")
    hi = ps.eigenvalues(1.07 * ue, beta, "clamped-free")
    assert np.min(lo.imag) > 0
    grow = hi[hi.imag < 0]
    assert grow.size == 1 and abs(grow[0].real - we) < 0.2 * we


def test_cantilever_published_thresholds():
    # Païdoussis (1998) §3.5.1, after Gregory & Païdoussis (1966): the Hopf bifurcation
    # "at u = u_cf ≈ 5.6 and 7.0, for β = 0.2 and 0.295" (printed to two digits), and for
    # β = 0.295 "for 7 < u < 8.2, the system loses stability, regains it and loses it
    # again". β = 0.295 sits on the S-shaped part of the curve, where the growth rate
    # dips below zero by only 0.065 and the crossing is sensitive: we find 7.27 (4 %).
    assert abs(ps.critical_flow_velocity(0.2, "clamped-free", du=0.1)[0] - 5.6) < 0.05
    u1 = ps.critical_flow_velocity(0.295, "clamped-free", du=0.02)[0]
    assert abs(u1 - 7.0) < 0.3
    growth = lambda u: -np.min(ps.eigenvalues(u, 0.295, "clamped-free").imag)  # noqa: E731
    assert growth(7.5) > 0 and growth(8.05) < 0 and growth(8.35) > 0


def test_cantilever_jump_near_beta_069():
    # Païdoussis (1998) §3.5.1: near β ≈ 0.69 u_cf jumps from ≈ 11 to ≈ 12.8 (S-shaped curve)
    lo = ps.critical_flow_velocity(0.68, "clamped-free", du=0.02)[0]
    hi = ps.critical_flow_velocity(0.70, "clamped-free", du=0.02)[0]
    assert 10.5 < lo < 11.6 and 12.3 < hi < 13.3


def test_hanging_cantilever_table_3_4():
    # Païdoussis (1998) Table 3.4 (Païdoussis 1970), undamped theory: hanging
    # cantilevers conveying air, (β, γ) -> (u_cf, ω_cf)
    for beta, gamma, u_pub, w_pub in ((0.23e-3, 61.1, 6.15, 21.3), (2.03e-3, 42.4, 5.62, 19.5)):
        u, w, kind = ps.critical_flow_velocity(beta, "clamped-free", gamma=gamma, du=0.1)
        assert kind == "flutter"
        assert abs(u - u_pub) < 0.01 and abs(w - w_pub) < 0.1
        # the exact determinant (Magnus-integrated, variable tension) has a real root there
        om = ps.exact_eigenvalue(w, u, beta, "clamped-free", gamma=gamma, n_steps=100)
        assert abs(om.imag) < 1e-5 and abs(om.real - w) < 1e-4


def test_standing_cantilever_buckles_at_the_bessel_zero():
    # a standing cantilever (γ < 0) buckles under its own weight when
    # J_{-1/3}((2/3) (-γ)^{1/2}) = 0 (Païdoussis 1998 §3.5.3): γ ≈ -7.837
    j = optimize.brentq(lambda x: special.jv(-1.0 / 3.0, x), 1.0, 2.5, xtol=1e-15)
    gamma_c = -(1.5 * j) ** 2
    f = lambda g: ps.characteristic_determinant(0.0, 0.0, 0.5, "clamped-free", gamma=g).real  # noqa: E731
    g_exact = optimize.brentq(f, -9.0, -7.0, xtol=1e-13)
    assert abs(g_exact - gamma_c) < 1e-7
    stable = ps.eigenvalues(0.0, 0.5, "clamped-free", gamma=gamma_c + 0.01)
    buckled = ps.eigenvalues(0.0, 0.5, "clamped-free", gamma=gamma_c - 0.01)
    assert np.min(stable.imag) > -1e-8 and np.min(buckled.imag) < -1e-2


def test_dimensional_helpers_round_trip():
    EI, M, m, L, g = 0.05, 0.2, 0.3, 1.5, 9.81
    U = 7.0
    u, beta, gamma, t_ref = ps.dimensionless_parameters(EI, M, m, L, U, g)
    assert np.isclose(u, U * L * np.sqrt(M / EI)) and np.isclose(beta, 0.4)
    assert np.isclose(gamma, (M + m) * g * L**3 / EI)
    assert np.isclose(ps.flow_velocity(u, EI, M, L), U)
    assert np.isclose(ps.dimensionless_flow_velocity(U, EI, M, L), u)
    assert np.isclose(ps.frequency_hz(2 * np.pi, EI, M, m, L) * t_ref, 1.0)


def test_bad_arguments_are_one_line_errors():
    with pytest.raises(VarintError, match="ends must be one of"):
        ps.eigenvalues(1.0, 0.2, "free-free")
    with pytest.raises(VarintError, match="beta"):
        ps.critical_flow_velocity(1.5, "clamped-free")
    with pytest.raises(VarintError, match="EI must be > 0"):
        ps.dimensionless_parameters(0.0, 1.0, 1.0, 1.0)
