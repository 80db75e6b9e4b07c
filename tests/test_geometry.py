"""The parcel-volume kernels against plain quadrature and finite differences (and their Python versions)."""

import numpy as np
import pytest
import scipy.sparse as sp

from varint.lattice import parcels as G


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
    V = G.parcel_volumes(s, R, ds, periodic)
    vol = G.tube_volume(R, ds, periodic)[0]
    assert np.sum(V) == pytest.approx(vol, rel=1e-13)
    if not periodic:
        # closed: the end labels sit on the tube's ends; a label moved inside the tube only shifts volume
        # between its two parcels, and dropping a label merges them exactly
        t = s.copy()
        t[3] = 0.5 * (s[3] + s[4])
        W = G.parcel_volumes(t, R, ds, False)
        assert np.sum(W) == pytest.approx(vol, rel=1e-13)
        assert W[2] > V[2] and W[3] < V[3]
        merged = G.parcel_volumes(np.delete(s, 3), R, ds, False)
        assert merged[2] == pytest.approx(V[2] + V[3], rel=1e-13)
    else:
        # periodic: the labels straddle the seam; every parcel is unchanged when the whole lattice is carried
        # once (or twice, or backwards) round the loop, and by a rotation of the radii by one element
        L = ds * len(R)
        for turns in (1, 2, -1):
            assert np.allclose(G.parcel_volumes(s + turns * L, R, ds, True), V, rtol=1e-12, atol=0)
        assert np.allclose(G.parcel_volumes(s + ds, np.roll(R, 1), ds, True), V, rtol=1e-12, atol=0)


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


# -- an independent NumPy reference -----------------------------------------------------------------
#
# Written from the definitions, not from the kernels' closed form: R(x) = sum_j R_j phi_j(x) with hat
# functions phi_j, V_k = int_{s_k}^{s_{k+1}} pi R(x)^2 dx by Gauss-Legendre on each piece between nodes
# (3 points integrate the quadratic and quartic integrands exactly), and
#   dV_k/dR_j = int 2 pi R phi_j,     d2V_k/dR_i dR_j = int 2 pi phi_i phi_j,
#   dV_k/ds_{k+1} = pi R(s_{k+1})^2,  d2V_k/ds_{k+1}^2 = 2 pi R R'(s_{k+1}),  d2V_k/ds_{k+1} dR_j = 2 pi R phi_j(s_{k+1}),
# and the same with a minus sign at s_k.


def _hats(x, nR, ds, periodic):
    """phi_j(x) and phi_j'(x) at the points x (rows), for the nR nodal hat functions."""
    x = np.atleast_1d(np.asarray(x, dtype=float))
    e = np.floor(x / ds)
    if not periodic:
        e = np.clip(e, 0, nR - 2)
    t = x / ds - e
    e = e.astype(np.int64)
    ja, jb = (e % nR, (e + 1) % nR) if periodic else (e, e + 1)
    rows = np.arange(len(x))
    phi, dphi = np.zeros((len(x), nR)), np.zeros((len(x), nR))
    np.add.at(phi, (rows, ja), 1 - t)
    np.add.at(phi, (rows, jb), t)
    np.add.at(dphi, (rows, ja), -1 / ds)
    np.add.at(dphi, (rows, jb), 1 / ds)
    return phi, dphi


def _reference(s, R, ds, periodic, c1, c2):
    """V (M,), dV/dq (M, n) and sum_k c2_k grad V_k grad V_k^T + c1_k hess V_k (n, n), q = [s | R]."""
    nlab, nR = len(s), len(R)
    M, n = nlab - 1, nlab + nR
    xg, wg = np.polynomial.legendre.leggauss(3)
    V, J, H = np.zeros(M), np.zeros((M, n)), np.zeros((n, n))
    for k in range(M):
        a, b = s[k], s[k + 1]
        cuts = np.arange(np.floor(a / ds) + 1, np.ceil(b / ds)) * ds
        pts = np.concatenate([[a], cuts[(cuts > a) & (cuts < b)], [b]])
        lo, hi = pts[:-1, None], pts[1:, None]
        x = (0.5 * (lo + hi) + 0.5 * (hi - lo) * xg).ravel()
        w = (0.5 * (hi - lo) * wg).ravel()
        phi, _ = _hats(x, nR, ds, periodic)
        r = phi @ R
        V[k] = np.sum(w * np.pi * r * r)
        hk = np.zeros((n, n))
        J[k, nlab:] = (w * 2 * np.pi * r) @ phi
        hk[nlab:, nlab:] = (phi.T * (w * 2 * np.pi)) @ phi
        for i, sign in ((k, -1.0), (k + 1, 1.0)):
            ph, dph = _hats(s[i], nR, ds, periodic)
            ri, dri = float(ph[0] @ R), float(dph[0] @ R)
            J[k, i] = sign * np.pi * ri * ri
            hk[i, i] = sign * 2 * np.pi * ri * dri
            hk[i, nlab:] = hk[nlab:, i] = sign * 2 * np.pi * ri * ph[0]
        H += c2[k] * np.outer(J[k], J[k]) + c1[k] * hk
    return V, J, H


def _dense(coo, shape):
    return sp.coo_matrix((coo[2], (coo[0], coo[1])), shape=shape).toarray()


LATTICES = [dict(nlab=9, N=7), dict(nlab=31, N=5), dict(nlab=4, N=23)]  # ~1, ~6 parcels per element, ~8 elements per parcel


@pytest.mark.parametrize("lattice", LATTICES, ids=["mixed", "fine-parcels", "long-parcels"])
@pytest.mark.parametrize("periodic", [False, True])
def test_kernels_against_numpy_reference(periodic, lattice):
    s, R, ds = _case(periodic, seed=11, **lattice)
    M, nlab, nR = len(s) - 1, len(s), len(R)
    n = nlab + nR
    rng = np.random.default_rng(2)
    c1, c2 = rng.standard_normal(M), rng.standard_normal(M)
    Vref, Jref, Href = _reference(s, R, ds, periodic, c1, c2)
    V = np.empty(M)
    G._volumes(s, R, ds, periodic, V)
    assert np.allclose(V, Vref, rtol=1e-13, atol=0)
    gs, gR, H, J = G._derivatives(s, R, ds, periodic, c1, c2, True, True)
    g = c1 @ Jref
    scale = np.abs(g).max()
    assert np.allclose(gs, g[:nlab], rtol=0, atol=1e-13 * scale)
    assert np.allclose(gR, g[nlab:], rtol=0, atol=1e-13 * scale)
    assert np.allclose(_dense(J, (M, n)), Jref, rtol=0, atol=1e-13 * np.abs(Jref).max())
    assert np.allclose(_dense(H, (n, n)), Href, rtol=0, atol=1e-12 * np.abs(Href).max())
    # radii as data: label derivatives only
    gs2, gR2, H2, J2 = G._derivatives(s, R, ds, periodic, c1, c2, False, True)
    assert np.array_equal(gs2, gs) and not gR2.any()
    Hs = np.zeros_like(Href)
    Hs[:nlab, :nlab] = Href[:nlab, :nlab]
    assert np.allclose(_dense(H2, (n, n)), Hs, rtol=0, atol=1e-12 * np.abs(Href).max())
    Js = np.zeros_like(Jref)
    Js[:, :nlab] = Jref[:, :nlab]
    assert np.allclose(_dense(J2, (M, n)), Js, rtol=0, atol=1e-13 * np.abs(Jref).max())


def test_numpy_reference_against_quadrature_and_differences():
    """The reference itself: volumes against scipy's quad, its gradient against differences of its volumes."""
    for periodic in (False, True):
        s, R, ds = _case(periodic, seed=4)
        M = len(s) - 1
        c = np.ones(M)
        V, J, _ = _reference(s, R, ds, periodic, c, c)
        assert np.allclose(V, G.parcel_volumes_reference(s, R, ds, periodic), rtol=1e-12, atol=0)
        q = np.concatenate([s, R])
        eps = 1e-7
        for i in range(len(q)):
            e = np.zeros(len(q))
            e[i] = eps
            up = _reference((q + e)[:len(s)], (q + e)[len(s):], ds, periodic, c, c)[0]
            dn = _reference((q - e)[:len(s)], (q - e)[len(s):], ds, periodic, c, c)[0]
            assert np.allclose((up - dn) / (2 * eps), J[:, i], rtol=0, atol=1e-7 * np.abs(J).max())


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


def test_volume_below_is_the_parcel_volumes_running_sum():
    """volume_below (the open ducts' F(s) = int_0^s A) is the parcel kernels' element integral: its differences are the
    parcel volumes, its value at L the tube's volume."""
    from varint.lattice.parcels import volume_below

    rng = np.random.default_rng(8)
    n, L = 9, 1.3
    ds = L / (n - 1)
    R = 0.05 * (1 + 0.2 * rng.uniform(-1, 1, n))
    s = np.r_[0.0, np.sort(rng.uniform(0, L, 12)), L]
    F = volume_below(s, R, ds)
    V = G.parcel_volumes(s, R, ds, False)
    assert np.abs(np.diff(F) - V).max() < 1e-15 * V.max() * len(s)
    assert float(volume_below(L, R, ds)) == pytest.approx(G.tube_volume(R, ds, False)[0], rel=1e-15)
    assert volume_below(0.0, R, ds) == 0.0
