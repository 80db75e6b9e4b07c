"""The fluid's kinetic step term on the moving centreline (docs/theory.md §10.4) against finite
differences of its own action, its symmetries (the Noether momenta of §10.6) and the straight tube."""

import math

import numpy as np
import pytest

from varint.coupled_terms import fluid_kinetic_step

RNG = np.random.default_rng(11)
H = 1e-3


def _state(periodic, n_nodes=7, M=9, L=1.2):
    ds = L / (n_nodes if periodic else n_nodes - 1)
    sj = np.arange(n_nodes) * ds
    r0 = np.stack([sj + 0.05 * np.sin(3 * sj), 0.2 * np.sin(2 * sj), 0.1 * sj ** 2], axis=1)
    r1 = r0 + 0.01 * RNG.standard_normal(r0.shape)
    if periodic:
        # periodic: r_{j+N} = r_j + L e_1, so the displacement must be periodic too (it is: any nodal values)
        r0[:, 1:] = np.stack([0.2 * np.sin(2 * np.pi * sj / L), 0.1 * np.cos(2 * np.pi * sj / L)], axis=1)
        r1 = r0 + 0.01 * RNG.standard_normal(r0.shape)
        base = np.sort(RNG.uniform(0, L, M - 1))
        s0 = np.concatenate([[0.1], 0.1 + base, [0.1 + L]])
    else:
        s0 = np.concatenate([[0.0], np.sort(RNG.uniform(0, L, M - 1)), [L]])
    s1 = s0.copy()
    s1[1:-1] += 0.002 * RNG.standard_normal(M - 1)
    if periodic:
        s1[0] += 0.001
        s1[-1] = s1[0] + L
    mbar = RNG.uniform(0.5, 1.5, M + 1)
    return s0, r0, s1, r1, mbar, ds


def _pack(s0, r0, s1, r1):
    return np.concatenate([s0, r0.ravel(), s1, r1.ravel()])


def _unpack(x, n_lab, n_nodes):
    a = n_lab + 3 * n_nodes
    return x[:n_lab], x[n_lab:a].reshape(n_nodes, 3), x[a:a + n_lab], x[a + n_lab:].reshape(n_nodes, 3)


def _dense(index, local, n):
    out = np.zeros((n,) * (local.ndim - 1))
    for idx, v in zip(index, local):
        if v.ndim == 1:
            np.add.at(out, idx, v)
        else:
            np.add.at(out, (idx[:, None], idx[None, :]), v)
    return out


@pytest.mark.parametrize("periodic", [False, True], ids=["closed", "periodic"])
def test_gradient_and_hessian_equal_central_differences(periodic):
    s0, r0, s1, r1, mbar, ds = _state(periodic)
    n_lab, n_nodes = len(s0), len(r0)
    x0 = _pack(s0, r0, s1, r1)
    L, index, grad, hess = fluid_kinetic_step(s0, r0, s1, r1, mbar, H, ds, periodic)
    g = _dense(index, grad, len(x0))
    Hm = _dense(index, hess, len(x0))
    assert np.max(np.abs(Hm - Hm.T)) <= 1e-12 * np.max(np.abs(Hm))

    def action(x):
        return fluid_kinetic_step(*_unpack(x, n_lab, n_nodes), mbar, H, ds, periodic)[0]

    def gradient(x):
        _, idx, gr, _ = fluid_kinetic_step(*_unpack(x, n_lab, n_nodes), mbar, H, ds, periodic)
        return _dense(idx, gr, len(x))

    step = 1e-6
    g_fd = np.zeros_like(x0)
    H_fd = np.zeros((len(x0), len(x0)))
    # a closed tube's end labels are fixed at s = 0, L (no variation leaves the centreline): not varied
    ends = [0, n_lab - 1, n_lab + 3 * n_nodes, 2 * n_lab + 3 * n_nodes - 1]
    varied = [i for i in range(len(x0)) if periodic or i not in ends]
    for i in varied:
        e = np.zeros_like(x0)
        e[i] = step
        g_fd[i] = (action(x0 + e) - action(x0 - e)) / (2 * step)
        H_fd[:, i] = (gradient(x0 + e) - gradient(x0 - e)) / (2 * step)
    assert np.max(np.abs(g - g_fd)[varied]) < 1e-7 * np.max(np.abs(g))
    assert np.max(np.abs(Hm - H_fd)[:, varied]) < 1e-6 * np.max(np.abs(Hm))


def test_straight_tube_reduces_to_the_labels_kinetic_energy():
    n_nodes, L = 7, 1.2
    ds = L / (n_nodes - 1)
    straight = np.stack([np.arange(n_nodes) * ds, np.zeros(n_nodes), np.zeros(n_nodes)], axis=1)
    s0, _, s1, _, mbar, _ = _state(False)
    val = fluid_kinetic_step(s0, straight, s1, straight, mbar, H, ds)[0]
    assert val == pytest.approx(np.sum(0.5 * mbar * (s1 - s0) ** 2) / H, rel=1e-13)


def test_invariant_under_rigid_motions_and_its_noether_momenta():
    s0, r0, s1, r1, mbar, ds = _state(False)
    n_lab, n_nodes = len(s0), len(r0)
    L, index, grad, _ = fluid_kinetic_step(s0, r0, s1, r1, mbar, H, ds)
    a = np.array([0.4, -0.9, 1.3])
    th = np.linalg.norm(a)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]]) / th
    Q = np.eye(3) + math.sin(th) * K + (1 - math.cos(th)) * K @ K
    c = np.array([3.0, -1.0, 2.0])
    moved = fluid_kinetic_step(s0, r0 @ Q.T + c, s1, r1 @ Q.T + c, mbar, H, ds)[0]
    assert moved == pytest.approx(L, rel=1e-13)
    # infinitesimal symmetries: sum of the forces on the nodes at both levels is zero (translation), and
    # so is their moment (rotation); the labels do not move under either
    g = _dense(index, grad, len(_pack(s0, r0, s1, r1)))
    _, f0, _, f1 = _unpack(g, n_lab, n_nodes)
    scale = np.max(np.abs(f1))
    assert np.max(np.abs(f0.sum(0) + f1.sum(0))) < 1e-13 * scale * n_nodes
    moment = np.cross(r0, f0).sum(0) + np.cross(r1, f1).sum(0)
    assert np.max(np.abs(moment)) < 1e-13 * scale * n_nodes
    # the level-(n+1) node forces add up to the fluid's discrete linear momentum sum mbar (X1 - X0) / h
    from varint.coupled_geometry import centreline

    X0, X1 = centreline(s0, r0, ds)[0], centreline(s1, r1, ds)[0]
    P = np.sum(mbar[:, None] * (X1 - X0), axis=0) / H
    assert np.allclose(f1.sum(0), P, rtol=1e-13, atol=0)
