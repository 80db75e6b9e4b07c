"""Newton's stopping test knows the round-off floor of the state; divergence is still caught early.

0.1 behaviour pinned down here: on long lattices (10^5 parcels at the default newton_tol) the update
cannot get below ~eps |s| / (L / M), which is above newton_tol, so every step refreshed and refactorised
the Jacobian to declare "stagnated at round-off" (a 13x jump in step cost in docs/performance.md).
"""

import numpy as np
import pytest
import scipy.sparse as sp

from varint import Simulation
from varint.schemes.newton import EPS, newton

from varint.scene.standard import gas_scene
from helpers import make

# -- a synthetic problem with the tube's structure: unknowns are displacements z from absolute positions c,
#    the residual sees c + z (a mass term plus a nonlinear stiffness on differences of positions)

N = 400
C = np.linspace(0.0, 1.0, N)
SCALE = np.full(N, 1e-6)  # the unknowns' natural size is a micro-fraction of the positions: floor eps |c| / scale ~ 2e-10
K, GAMMA = 0.3, 0.1


def _lap(x):
    y = np.empty_like(x)
    y[1:-1] = x[2:] - 2 * x[1:-1] + x[:-2]
    y[0] = x[1] - 2 * x[0]
    y[-1] = x[-2] - 2 * x[-1]
    return y


LAP_C = _lap(C)


def _residual(z, rhs):
    d = _lap(C + z) - LAP_C
    return z - K * (d + GAMMA * d ** 3 / SCALE[0] ** 2) - rhs


def _jacobian(z):
    d = _lap(C + z) - LAP_C
    w = 1 + 3 * GAMMA * d ** 2 / SCALE[0] ** 2
    L = sp.diags([np.ones(N - 1), -2 * np.ones(N), np.ones(N - 1)], [-1, 0, 1])
    return (sp.eye(N) - K * sp.diags(w) @ L).tocsc()


def test_floor_above_tol_stops_without_refactorising():
    tol = 1e-12
    rhs0 = 1e-3 * SCALE * np.sin(np.linspace(0, 3, N))
    z, factor, n_jac, errors = np.zeros(N), None, 0, []
    for call in range(8):  # like time steps: a slowly changing problem, the factorisation reused
        rhs = rhs0 * (1 + 0.05 * call)
        res = newton(lambda z: _residual(z, rhs), _jacobian, z, SCALE, tol, 25, factor, offset=C)
        assert res.converged, res.message
        assert res.iterations <= 4
        n_jac += res.n_jacobian
        errors.append(res.error)
        # the point returned is at round-off: a fresh full Newton step from it moves it by no more than the floor
        dz = sp.linalg.spsolve(_jacobian(res.z), -_residual(res.z, rhs))
        assert np.max(np.abs(dz) / SCALE) < 10 * EPS * np.max(np.abs(C + res.z) / SCALE)
        z, factor = res.z, res.factor
    assert min(errors) > tol  # the floor really is above tol here
    assert n_jac == 1  # the first call's factorisation serves all eight


def test_without_the_offset_the_floor_is_unknown_and_newton_refreshes():
    """The same problem without telling Newton where the state's round-off comes from: it cannot tell
    round-off from a stale Jacobian and pays a refresh per call (the 0.1 behaviour for the tube)."""
    rhs0 = 1e-3 * SCALE * np.sin(np.linspace(0, 3, N))
    z, factor, n_jac = np.zeros(N), None, 0
    for call in range(4):
        rhs = rhs0 * (1 + 0.05 * call)
        res = newton(lambda z: _residual(z, rhs), _jacobian, z, SCALE, 1e-12, 25, factor)
        assert res.converged
        n_jac += res.n_jacobian
        z, factor = res.z, res.factor
    assert n_jac >= 4


@pytest.mark.parametrize("parcels, tol", [(30_000, 2e-13), (100_000, None)], ids=["3e4-tight-tol", "1e5-default-tol"])
def test_long_lattice_steps_reuse_the_jacobian(parcels, tol):
    """Dynamic-wall gas tube, h = 0.2 ds / c: after the first step no step refactorises the Jacobian."""
    M = parcels
    pulse = [{"field": "pressure", "shape": "gaussian", "amplitude": 2e3, "center": 0.5, "width": 0.1}]
    _, model = make(gas_scene(nodes=M + 1, parcels=M, h=0.2 / M / 340.0, perturbation=pulse))
    sim = Simulation(model, tol=tol)
    sim.step()
    assert sim.stats.n_jacobian == 1
    per_step = []
    for _ in range(5):
        sim.step()
        per_step.append((sim.stats.n_jacobian, sim.stats.iterations))
    assert all(j == 0 for j, _ in per_step), per_step
    assert all(it <= 3 for _, it in per_step), per_step


# -- divergence is caught early, whatever the round-off band


def _cube_root():
    # Newton on cbrt(x) maps x -> -2x: every update doubles, and stays finite for ~1000 iterations
    F = lambda x: np.cbrt(x)  # noqa: E731
    J = lambda x: sp.diags(1.0 / (3.0 * np.cbrt(x) ** 2)).tocsc()  # noqa: E731
    return F, J


@pytest.mark.parametrize("offset", [None, 1e6])
def test_diverging_map_is_reported_within_a_few_iterations(offset):
    """Without the early detection this runs to max_iter (60) and says "no convergence"."""
    F, J = _cube_root()
    off = None if offset is None else np.full(1, offset)
    res = newton(F, J, np.array([0.7]), np.ones(1), 1e-12, 60, offset=off)
    assert not res.converged
    assert res.message == "diverging"
    assert res.iterations <= 8


def test_divergence_starting_inside_the_roundoff_band_is_still_divergence():
    """Updates that grow from the first one on never count as round-off, even inside the round-off band."""
    F, J = _cube_root()
    c = 1e9  # the residual sees c + x, so its round-off band is 100 eps c = 2.2e-5 wide
    band = 100 * EPS * c
    res = newton(lambda x: F((c + x) - c), lambda x: J((c + x) - c), np.array([0.1 * band]), np.ones(1), 1e-12, 60,
                 offset=np.full(1, c))
    assert not res.converged and res.message == "diverging" and res.iterations <= 8


def test_a_slow_mode_of_another_kind_is_not_taken_for_round_off():
    """A label far from the origin (absolute position 1e6, scale 1) beside a radius (scale 0.1, no
    offset): when the chord iteration's fast label mode dies and the slow radius mode takes over, the
    rate jumps from 0.01 to 0.9 inside the label's round-off band (2e-8).  The radius is then still
    7e-9 off, far above its own floor (~1e-24): Newton must refresh and converge it, not stop at the
    label's floor (one global floor did: 'stopped at the round-off floor' with that error)."""
    import scipy.sparse as sp

    from varint.schemes.newton import factorize

    J = sp.diags([0.99, 0.1]).tocsc()
    exact = np.array([1e-6 / 0.99, 1e-8])
    b = J @ exact
    scale = np.array([1.0, 0.1])
    res = newton(lambda z: J @ z - b, lambda z: J, np.zeros(2), scale, 1e-12, 50,
                 factor=factorize(sp.eye(2).tocsc()), offset=np.array([1e6, 0.0]))
    assert res.converged
    assert np.max(np.abs(res.z - exact) / scale) < 1e-12, (res.message, res.z - exact)
    assert res.n_jacobian >= 1  # it had to refresh the stale factorisation to get there
