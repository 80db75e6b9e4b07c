"""The parcel-volume kernels against plain quadrature and finite differences (and their Python versions)."""

import numpy as np
import pytest
import scipy.sparse as sp

from varint import geometry as G


def _case(periodic, seed=0, nlab=9, N=7):
    rng = np.random.default_rng(seed)
    ds = 1.0 / N
    R = 0.05 * (1 + 0.3 * rng.random(N if periodic else N + 1))
    s = np.sort(rng.random(nlab - 2))
    if periodic:
        s = np.concatenate([s, [s[0] + 1.0]]) - 0.3  # labels straddle the period seam
    else:
        s = np.concatenate([[0.0], s, [1.0]])
    return s, R, ds


@pytest.mark.parametrize("periodic", [False, True])
def test_volumes_match_quadrature(periodic):
    s, R, ds = _case(periodic)
    V = G.parcel_volumes(s, R, ds, periodic)
    assert np.allclose(V, G.parcel_volumes_reference(s, R, ds, periodic), rtol=1e-12, atol=0)


@pytest.mark.parametrize("periodic", [False, True])
def test_volumes_sum_to_tube_volume(periodic):
    s, R, ds = _case(periodic)
    if not periodic:
        assert np.sum(G.parcel_volumes(s, R, ds, periodic)) == pytest.approx(G.tube_volume(R, ds, periodic)[0], rel=1e-13)
    else:
        assert np.sum(G.parcel_volumes(s, R, ds, periodic)) == pytest.approx(G.tube_volume(R, ds, periodic)[0], rel=1e-13)


@pytest.mark.parametrize("periodic", [False, True])
def test_derivatives_against_finite_differences(periodic):
    s, R, ds = _case(periodic, seed=3)
    M = len(s) - 1
    rng = np.random.default_rng(5)
    c1, c2 = rng.standard_normal(M), rng.standard_normal(M)
    gs, gR, H, J = G.parcel_derivatives(s, R, ds, periodic, c1, c2, True, True)
    q = np.concatenate([s, R])
    n, nl = len(q), len(s)
    vol = lambda q: G.parcel_volumes(q[:nl], q[nl:], ds, periodic)  # noqa: E731

    def grad(q):
        a, b, _, _ = G.parcel_derivatives(q[:nl], q[nl:], ds, periodic, c1, c2, True, False)
        return np.concatenate([a, b])

    eps = 1e-6
    E = np.eye(n) * eps
    Jfd = np.array([(vol(q + E[i]) - vol(q - E[i])) / (2 * eps) for i in range(n)]).T
    gfd = Jfd.T @ c1
    Hfd = np.array([(grad(q + E[i]) - grad(q - E[i])) / (2 * eps) for i in range(n)]).T + (Jfd.T * c2) @ Jfd
    assert np.allclose(np.concatenate([gs, gR]), gfd, atol=1e-9)
    assert np.allclose(sp.coo_matrix((J[2], (J[0], J[1])), shape=(M, n)).toarray(), Jfd, atol=1e-9)
    Hm = sp.coo_matrix((H[2], (H[0], H[1])), shape=(n, n)).toarray()
    assert np.allclose(Hm, Hfd, atol=1e-7 * np.abs(Hm).max())
    assert np.allclose(Hm, Hm.T)


def test_kernels_equal_their_python_versions():
    s, R, ds = _case(False, seed=8)
    V = np.empty(len(s) - 1)
    G._volumes.py_func(s, R, ds, False, V)
    assert np.allclose(V, G.parcel_volumes(s, R, ds, False), rtol=1e-15)
    c = np.ones(len(s) - 1)
    fast = G._derivatives(s, R, ds, False, c, c, True, True)
    slow = G._derivatives.py_func(s, R, ds, False, c, c, True, True)
    assert np.allclose(fast[0], slow[0]) and np.allclose(fast[1], slow[1])
    assert np.allclose(fast[2][2], slow[2][2])


def test_label_exactly_on_a_node_is_continuous():
    """V is C^1: crossing a node changes the volume smoothly (no jump in value or slope)."""
    N, ds = 4, 0.25
    R = np.array([0.05, 0.06, 0.045, 0.05, 0.055])
    f = lambda x: G.parcel_volumes(np.array([0.0, x, 1.0]), R, ds, False)[0]  # noqa: E731
    x0, e = 0.5, 1e-9
    assert abs(f(x0 + e) - f(x0 - e)) < 3 * e * np.pi * 0.045 ** 2
    slope_l = (f(x0) - f(x0 - 1e-6)) / 1e-6
    slope_r = (f(x0 + 1e-6) - f(x0)) / 1e-6
    assert slope_l == pytest.approx(np.pi * 0.045 ** 2, rel=1e-4)
    assert slope_r == pytest.approx(np.pi * 0.045 ** 2, rel=1e-4)
