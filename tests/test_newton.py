"""The Newton solver as a pure function: convergence, Jacobian reuse, divergence as a value."""

import numpy as np
import scipy.sparse as sp

from varint.schemes.newton import newton


def _problem(c):
    # x_i^3 + x_i - c_i = 0, a diagonal-dominant nonlinear system
    F = lambda x: x ** 3 + x - c  # noqa: E731
    J = lambda x: sp.diags(3 * x ** 2 + 1).tocsc() + sp.diags(np.full(len(x) - 1, 1e-3), 1)  # noqa: E731
    return F, J


# The solver is a chord method with Jacobian refresh, built for the stepper's good predictor:
# starting points are within ~20 % of the root, as a time step's extrapolation is.
X0 = 0.8 * np.linspace(0.5, 2.0, 50) ** (1 / 3)


def test_converges_from_a_nearby_guess():
    c = np.linspace(0.5, 2.0, 50)
    F, J = _problem(c)
    res = newton(F, J, X0, np.ones(50), 1e-13, 30)
    assert res.converged and res.iterations <= 15
    assert np.max(np.abs(F(res.z))) < 1e-12


def test_reused_factor_refreshes_when_stale_and_counts_work():
    c = np.linspace(0.5, 2.0, 50)
    F, J = _problem(c)
    first = newton(F, J, X0, np.ones(50), 1e-12, 40)
    assert first.converged and first.n_jacobian >= 1
    # a nearby problem: reuse the old factorisation
    F2, _ = _problem(c * 1.01)
    second = newton(F2, J, first.z, np.ones(50), 1e-12, 40, factor=first.factor)
    assert second.converged
    assert second.n_jacobian <= 1  # at most one refresh
    assert second.n_residual == second.iterations


def test_divergence_is_reported_not_raised():
    F = lambda x: np.arctan(x)  # noqa: E731  Newton diverges from |x0| > 1.39
    J = lambda x: sp.diags(1 / (1 + x ** 2)).tocsc()  # noqa: E731
    res = newton(F, J, np.array([3.0]), np.ones(1), 1e-12, 20)
    assert not res.converged
    assert res.message in ("diverging", "residual is not finite", "no convergence within max_iterations")
