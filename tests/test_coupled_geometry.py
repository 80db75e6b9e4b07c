"""The coupled tube's geometry kernels (docs/theory.md §10.2, §10.3) against independent references.

Volumes against adaptive quadrature of pi R(s)^2 gamma(s) with R and gamma interpolated by numpy;
derivatives against central differences of the volumes; the Catmull–Rom centreline against the
properties §10.2 relies on (partition of unity, interpolation, exactness on quadratics, C^1 at nodes,
rigid-motion equivariance).
"""

import math

import numpy as np
import pytest
from scipy.integrate import quad

from varint.lattice.centreline import (centreline, centreline_weights, nodal_stretch, stretched_volume_derivatives, stretched_volumes)
from varint.lattice.parcels import parcel_volumes

RNG = np.random.default_rng(7)


def _lattice(periodic, n_el=6, parcels=9, L=1.2):
    ds = L / n_el
    nR = n_el if periodic else n_el + 1
    R = 0.1 + 0.03 * RNG.uniform(-1, 1, nR)
    gamma = 1.0 + 0.2 * RNG.uniform(-1, 1, nR)
    inner = np.sort(RNG.uniform(0, L, parcels - 1))
    if periodic:
        s0 = RNG.uniform(-0.3, 0.3)
        s = np.concatenate([[s0], s0 + inner, [s0 + L]])
    else:
        s = np.concatenate([[0.0], inner, [L]])
    return s, R, gamma, ds


def _interp(x, vals, ds, periodic):
    """Linear interpolation of nodal values at x, written independently of the kernels."""
    n = len(vals)
    if periodic:
        xp = np.arange(n + 1) * ds
        return np.interp(np.mod(x, n * ds), xp, np.append(vals, vals[0]))
    return np.interp(x, np.arange(n) * ds, vals)


def _quad_volumes(s, R, gamma, ds, periodic):
    f = lambda x: math.pi * _interp(x, R, ds, periodic) ** 2 * _interp(x, gamma, ds, periodic)  # noqa: E731
    out = []
    for a, b in zip(s[:-1], s[1:]):
        pts = np.arange(math.floor(a / ds) + 1, math.ceil(b / ds)) * ds
        cuts = np.concatenate([[a], pts[(pts > a) & (pts < b)], [b]])
        out.append(sum(quad(f, lo, hi, epsabs=0, epsrel=1e-13)[0] for lo, hi in zip(cuts[:-1], cuts[1:])))
    return np.array(out)


@pytest.mark.parametrize("periodic", [False, True], ids=["closed", "periodic"])
def test_volumes_equal_quadrature(periodic):
    s, R, gamma, ds = _lattice(periodic)
    V = stretched_volumes(s, R, gamma, ds, periodic)
    ref = _quad_volumes(s, R, gamma, ds, periodic)
    assert np.max(np.abs(V / ref - 1)) < 1e-12


@pytest.mark.parametrize("periodic", [False, True], ids=["closed", "periodic"])
def test_unit_stretch_gives_the_straight_tube_volumes(periodic):
    s, R, _, ds = _lattice(periodic)
    V = stretched_volumes(s, R, np.ones_like(R), ds, periodic)
    assert np.max(np.abs(V / parcel_volumes(s, R, ds, periodic) - 1)) < 1e-13


def test_a_uniform_stretch_scales_every_volume():
    s, R, _, ds = _lattice(False)
    V1 = stretched_volumes(s, R, np.ones_like(R), ds)
    assert np.allclose(stretched_volumes(s, R, np.full_like(R, 1.37), ds), 1.37 * V1, rtol=1e-14, atol=0)


@pytest.mark.parametrize("periodic", [False, True], ids=["closed", "periodic"])
def test_gradient_and_hessian_equal_central_differences(periodic):
    s, R, gamma, ds = _lattice(periodic)
    M, nR = len(s) - 1, len(R)
    V, index, grad, hess = stretched_volume_derivatives(s, R, gamma, ds, periodic)
    assert np.allclose(V, stretched_volumes(s, R, gamma, ds, periodic), rtol=1e-15, atol=0)
    x0 = np.concatenate([s, R, gamma])

    def vols(x):
        return stretched_volumes(x[:M + 1], x[M + 1:M + 1 + nR], x[M + 1 + nR:], ds, periodic)

    def dense(k, what):
        out = np.zeros(len(x0)) if what == "grad" else np.zeros((len(x0), len(x0)))
        use = index[k] >= 0
        if what == "grad":
            np.add.at(out, index[k][use], grad[k][use])
        else:
            ii = index[k][use]
            np.add.at(out, (ii[:, None], ii[None, :]), hess[k][np.ix_(use, use)])
        return out

    # a variable's step: labels must stay ordered (and the end labels of a periodic tube move together
    # with the period in the model; here each is varied alone, which the volumes allow)
    step = 1e-6
    G_fd = np.zeros((M, len(x0)))
    H_fd = np.zeros((M, len(x0), len(x0)))
    for i in range(len(x0)):
        e = np.zeros(len(x0))
        e[i] = step
        G_fd[:, i] = (vols(x0 + e) - vols(x0 - e)) / (2 * step)
        H_fd[:, :, i] = (dense_grads_at(x0 + e, M, nR, ds, periodic) - dense_grads_at(x0 - e, M, nR, ds, periodic)) / (2 * step)
    for k in range(M):
        g = dense(k, "grad")
        scale = np.max(np.abs(g))
        assert np.max(np.abs(g - G_fd[k])) < 1e-7 * scale, f"parcel {k} gradient"
        H = dense(k, "hess")
        assert np.max(np.abs(H - H.T)) == 0.0
        assert np.max(np.abs(H - H_fd[k])) < 1e-6 * np.max(np.abs(H)), f"parcel {k} Hessian"


def dense_grads_at(x, M, nR, ds, periodic):
    """Every parcel's gradient as a dense (M, n) array, from the kernel at the point x."""
    _, index, grad, _ = stretched_volume_derivatives(x[:M + 1], x[M + 1:M + 1 + nR], x[M + 1 + nR:], ds, periodic)
    out = np.zeros((M, len(x)))
    for k in range(M):
        use = index[k] >= 0
        np.add.at(out[k], index[k][use], grad[k][use])
    return out


def test_bad_labels_are_refused_in_one_line():
    s, R, gamma, ds = _lattice(False)
    s[3], s[4] = s[4], s[3]
    with pytest.raises(ValueError, match="out of order"):
        stretched_volumes(s, R, gamma, ds)
    with pytest.raises(ValueError, match="same shape"):
        stretched_volumes(np.sort(s), R, gamma[:-1], ds)


def test_nodal_stretch_is_the_mean_of_the_adjacent_elements():
    g = np.array([1.0, 1.2, 0.9])
    assert np.allclose(nodal_stretch(g), [1.0, 1.1, 1.05, 0.9])
    assert np.allclose(nodal_stretch(g, periodic=True), [0.95, 1.1, 1.05])


# -- the Catmull–Rom centreline ------------------------------------------------------------------


def _curve(n_nodes=7, L=1.2):
    ds = L / (n_nodes - 1)
    sj = np.arange(n_nodes) * ds
    r = np.stack([np.cos(sj) + 0.3 * sj, np.sin(2 * sj), 0.2 * sj ** 3], axis=1)
    return r, ds, L


def test_weights_are_a_partition_of_unity_and_their_derivatives():
    r, ds, L = _curve()
    s = np.linspace(0, L, 97)
    nodes, N, dN, d2N = centreline_weights(s, len(r), ds)
    assert np.allclose(N.sum(1), 1.0, rtol=0, atol=1e-15)
    assert np.allclose(dN.sum(1), 0.0, rtol=0, atol=1e-13)
    assert np.allclose(d2N.sum(1), 0.0, rtol=0, atol=1e-11)
    assert nodes.min() >= 0 and nodes.max() <= len(r) - 1
    # derivatives of the weights against central differences of X itself (inside elements)
    x = np.array([0.05, 0.33, 0.61, 1.13])
    X, dX, d2X = centreline(x, r, ds)
    h = 1e-6
    Xp, dXp, _ = centreline(x + h, r, ds)
    Xm, dXm, _ = centreline(x - h, r, ds)
    assert np.allclose(dX, (Xp - Xm) / (2 * h), rtol=0, atol=1e-8)
    assert np.allclose(d2X, (dXp - dXm) / (2 * h), rtol=0, atol=1e-6)


def test_interpolates_the_nodes_and_is_exact_on_quadratics():
    r, ds, L = _curve()
    sj = np.arange(len(r)) * ds
    X, _, _ = centreline(sj, r, ds)
    assert np.allclose(X, r, rtol=0, atol=1e-15)
    # nodal positions of a quadratic curve: X reproduces it everywhere, end elements included
    q = np.stack([0.5 + sj, 2 * sj - sj ** 2, 0.3 * sj ** 2], axis=1)
    s = np.linspace(0, L, 61)
    X, dX, d2X = centreline(s, q, ds)
    assert np.allclose(X, np.stack([0.5 + s, 2 * s - s ** 2, 0.3 * s ** 2], axis=1), rtol=0, atol=1e-14)
    assert np.allclose(dX, np.stack([np.ones_like(s), 2 - 2 * s, 0.6 * s], axis=1), rtol=0, atol=1e-13)
    # a straight reference centreline r_j = j ds e_1 gives X = s e_1 (the straight tube of 0.1)
    straight = np.stack([sj, 0 * sj, 0 * sj], axis=1)
    assert np.allclose(centreline(s, straight, ds)[0][:, 0], s, rtol=0, atol=1e-15)


def test_tangent_is_continuous_at_nodes_and_curvature_jumps():
    r, ds, L = _curve()
    j = np.arange(1, len(r) - 1)
    eps = 1e-11
    _, dl, d2l = centreline(j * ds - eps, r, ds)
    _, dr, d2r = centreline(j * ds + eps, r, ds)
    assert np.max(np.abs(dl - dr)) < 1e-8
    assert np.max(np.abs(d2l - d2r)) > 1e-3  # C^1, not C^2: the Hessian of the kinetic term jumps at nodes


def test_moves_with_every_rigid_motion():
    r, ds, L = _curve()
    a = np.array([0.3, -1.1, 0.7])
    th = np.linalg.norm(a)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]]) / th
    Q = np.eye(3) + math.sin(th) * K + (1 - math.cos(th)) * K @ K
    c = np.array([5.0, -2.0, 1.0])
    s = np.linspace(0, L, 41)
    X, dX, _ = centreline(s, r, ds)
    Y, dY, _ = centreline(s, r @ Q.T + c, ds)
    assert np.allclose(Y, X @ Q.T + c, rtol=0, atol=1e-14)
    assert np.allclose(dY, dX @ Q.T, rtol=0, atol=1e-13)


def test_periodic_centreline_wraps_with_the_period():
    n, L = 8, 2.0
    ds = L / n
    sj = np.arange(n) * ds
    # a helix-like closed-by-period curve: r(s + L) = r(s) + L e_1
    r = np.stack([sj + 0.1 * np.sin(2 * np.pi * sj / L), np.cos(2 * np.pi * sj / L), np.sin(2 * np.pi * sj / L)], axis=1)
    s = np.array([-0.6, -0.01, 0.4, 1.9, 2.3])
    X, dX, _ = centreline(s, r, ds, periodic=True)
    Xs, dXs, _ = centreline(s + L, r, ds, periodic=True)
    assert np.allclose(Xs, X + [L, 0, 0], rtol=0, atol=1e-14)
    assert np.allclose(dXs, dX, rtol=0, atol=1e-13)
    assert np.allclose(centreline(sj, r, ds, periodic=True)[0], r, rtol=0, atol=1e-15)


def test_catmull_rom_kernels_are_the_basis_polynomials():
    """varint.lattice.centreline's compiled basis (k_cr_weights, k_cr_basis, k_cr_dd: the one Catmull-Rom basis, the
    coefficient table CR) against the polynomials written out, their derivatives and divided differences, real and
    complex; the em step's numpy twins (varint.schemes.em_tube._cr, _cr_dd) evaluate the same table; k_fold_ghost and
    k_cr_stencil fold a closed end's ghost as the dense fold of the numpy reference does."""
    from varint.lattice.centreline import CR, k_cr_basis, k_cr_dd, k_cr_stencil, k_cr_weights, k_fold_ghost
    from varint.schemes.em_tube import _cr, _cr_dd, _fold

    def written(t):  # the weights of nodes e-1..e+2 (docs/theory.md §10.2)
        return 0.5 * np.array([-t ** 3 + 2 * t ** 2 - t, 3 * t ** 3 - 5 * t ** 2 + 2, -3 * t ** 3 + 4 * t ** 2 + t, t ** 3 - t ** 2])

    rng = np.random.default_rng(3)
    for t in np.r_[0.0, 1.0, rng.uniform(0, 1, 6)]:
        w, dw, d2w = np.empty(4), np.empty(4), np.empty(4)
        k_cr_basis(t, w, dw, d2w)
        assert np.abs(w - written(t)).max() < 4e-16
        assert np.abs(dw - (written(t + 1e-6) - written(t - 1e-6)) / 2e-6).max() < 1e-8
        assert np.abs(d2w - (written(t + 1e-4) - 2 * written(t) + written(t - 1e-4)) / 1e-8).max() < 1e-6
        assert np.abs(w - _cr(np.array(t))).max() < 4e-16
        b = t + 0.3
        dd = np.empty(4)
        k_cr_dd(t, b, dd)
        assert np.abs(dd - (written(b) - written(t)) / 0.3).max() < 1e-14
        assert np.abs(dd - _cr_dd(np.array(t), np.array(b))).max() < 1e-15
        k_cr_dd(t, t, dd)
        assert np.array_equal(dd, dw)
        wc = np.empty(4, complex)
        k_cr_weights(t + 1e-30j, wc)
        assert np.abs(wc.real - w).max() < 1e-15 and np.abs(wc.imag / 1e-30 - dw).max() < 1e-15
    assert CR.shape == (4, 4) and np.allclose(CR.sum(0), [1, 0, 0, 0], atol=0)
    # a closed end's ghost: the stencil fold against the dense fold, at both ends of 3- and 6-node lattices
    for n_nodes in (3, 6):
        for e in (0, n_nodes - 2):
            w = rng.normal(size=4)
            nodes = np.empty(4, np.int64)
            slot = k_cr_stencil(e, n_nodes, False, nodes)
            assert slot == (0 if e == 0 else 3)
            dense = np.zeros(n_nodes + 2)
            dense[e + np.arange(4)] = w
            ref = _fold(dense, n_nodes)
            k_fold_ghost(slot, w)
            got = np.zeros(n_nodes)
            np.add.at(got, nodes, w)
            assert nodes.min() >= 0 and nodes.max() < n_nodes
            assert np.abs(got - ref).max() < 1e-15


def test_moment_kernels_are_the_element_integrals():
    """varint.lattice.centreline's moments (MQ, k_moments, k_moments_dd: the one table of the stretched volumes, for
    the coupled kernels and the energy-momentum step's pairs) against quadrature of (1 - tau)^(3-q) tau^q, their
    divided differences, complex steps; k_piece_volume with a unit stretch is the straight tube's element integral."""
    from varint.lattice.centreline import MQ, k_moments, k_moments_dd, k_piece_volume
    from varint.lattice.parcels import volume_below
    from varint.schemes.em_tube import _moments

    rng = np.random.default_rng(4)
    for t in np.r_[0.0, 1e-9, 1.0, rng.uniform(0, 1, 5)]:
        M = np.empty(4)
        k_moments(t, M)
        P = np.polynomial.Polynomial
        ref = [((P([1.0, -1.0]) ** (3 - q)) * P([0.0, 1.0]) ** q).integ()(t) for q in range(4)]  # exact antiderivatives
        assert np.abs(M - ref).max() < 4e-16 * max(t, 1e-16)
        assert np.abs(M - _moments(np.array(t), False)).max() < 1e-16
        Mc = np.empty(4, complex)
        k_moments(t + 1e-30j, Mc)
        assert np.abs(Mc.imag / 1e-30 - [(1 - t) ** (3 - q) * t ** q for q in range(4)]).max() < 1e-15
        dd, Mb = np.empty(4), np.empty(4)
        k_moments(t + 0.2, Mb)
        k_moments_dd(t, t + 0.2, dd)
        assert np.abs(dd - (Mb - M) / 0.2).max() < 1e-14
    assert MQ.shape == (4, 4)
    R, ds = np.array([0.05, 0.07]), 0.3
    for lo, hi in ((0.0, 1.0), (0.2, 0.9)):
        S, Sl = np.empty(4), np.empty(4)
        k_moments(hi, S)
        k_moments(lo, Sl)
        v = k_piece_volume(R[0], R[1], 1.0, 1.0, S - Sl, ds)
        F = volume_below(np.array([lo, hi]) * ds, R, ds)
        assert v == pytest.approx(F[1] - F[0], rel=1e-14)


def test_whole_element_volume_is_the_piece_volume_over_the_element():
    """k_whole_element (the tube's volume under the external pressure, its gradient and Hessian, for the coupled
    kernels and their numpy reference) is k_piece_volume over [0, 1], and its derivatives those of that polynomial."""
    from varint.lattice.centreline import k_moments, k_piece_volume, k_whole_element

    rng = np.random.default_rng(5)
    x = rng.uniform(0.5, 1.5, 4)
    S = np.empty(4)
    k_moments(1.0, S)
    w = k_whole_element(*x)
    assert w[0] == pytest.approx(12 * k_piece_volume(*x, S, 1.0) / np.pi, rel=1e-14)
    f = lambda y: k_whole_element(*y)[0]  # noqa: E731
    for i in range(4):
        e = np.zeros(4)
        e[i] = 1e-6
        assert w[1 + i] == pytest.approx((f(x + e) - f(x - e)) / 2e-6, rel=1e-8)
    H = np.zeros((4, 4))
    H[0, 0], H[1, 1], H[0, 1], H[0, 2], H[0, 3], H[1, 2], H[1, 3] = w[5:]
    H = H + np.triu(H, 1).T
    for i in range(4):
        e = np.zeros(4)
        e[i] = 1e-5
        gp, gm = np.array(k_whole_element(*(x + e))[1:5]), np.array(k_whole_element(*(x - e))[1:5])
        assert np.allclose((gp - gm) / 2e-5, H[i], rtol=1e-7, atol=1e-9)
    arr = k_whole_element(*(np.stack([x, x + 0.1]).T))  # elementwise on arrays (the numpy reference's use)
    assert arr[0][0] == pytest.approx(w[0], rel=1e-15)
