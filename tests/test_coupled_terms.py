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


# ---------------------------------------------------------------------------
# the fluid's potential part of the step (docs/theory.md §10.4.2) and both terms in the stepper's layout

from varint.coupled_geometry import centreline, nodal_stretch, stretched_volumes  # noqa: E402
from varint.coupled_terms import (FluidPotential, element_strains, fluid_kinetic_chart,  # noqa: E402
                                  fluid_potential_step, newton_offsets, stretch_map)
from varint.lie import cay, cay_inv  # noqa: E402
from varint.thermo import IdealGas, Tait  # noqa: E402

HP = 0.05          # a step long enough that the two levels differ visibly
GRAV = np.array([0.3, -0.2, -9.81])


def _rod(periodic, n_el, L, seed):
    """A bent, twisted rod at level n and a moved, turned, stretched copy at level n+1."""
    rng = np.random.default_rng(seed)
    ds = L / n_el
    n_nodes = n_el if periodic else n_el + 1
    if periodic:
        # r_{j+N} = r_j + L e_1: a periodic wiggle about the axis, frames periodic
        sj = np.arange(n_nodes) * ds
        ph = 2 * np.pi * sj / L
        r0 = np.stack([sj + 0.03 * np.sin(ph), 0.15 * np.sin(ph), 0.1 * np.cos(2 * ph)], axis=1)
        Lam0 = cay(np.stack([0.2 * np.sin(ph), 0.1 * np.cos(ph), 0.3 * np.sin(2 * ph)], axis=1))
    else:
        Lam0 = np.empty((n_nodes, 3, 3))
        r0 = np.zeros((n_nodes, 3))
        Lam0[0] = cay(0.3 * rng.normal(size=3))
        for j in range(n_el):
            Lam0[j + 1] = Lam0[j] @ cay(0.6 * ds * rng.normal(size=3))
            r0[j + 1] = r0[j] + Lam0[j] @ (np.array([1.0, 0, 0]) + 0.05 * rng.normal(size=3)) * ds
    r1 = r0 + 0.02 * rng.normal(size=r0.shape)
    Lam1 = Lam0 @ cay(0.1 * rng.normal(size=(n_nodes, 3)))
    return ds, Lam0, r0, Lam1, r1


def _case(kind, periodic=False, n_el=7, M=9, L=1.2, seed=3):
    """(FluidPotential, state dict) for one combination of terms.

    kind: 'gas' (ideal gas with entropy + p_ext + gravity), 'barotropic' (+ p_ext + gravity), 'liquid'
    (incompressible, random mu, + p_ext + gravity), and the terms alone on a liquid with mu = 0:
    'pext' (external pressure only), 'gravity' (gravity only).
    """
    rng = np.random.default_rng(seed + 100)
    ds, Lam0, r0, Lam1, r1 = _rod(periodic, n_el, L, seed)
    nR = len(r0)
    R0 = 0.1 * (1 + 0.1 * rng.uniform(-1, 1, nR))
    R1 = R0 * (1 + 0.02 * rng.normal(size=nR))
    inner = np.sort(rng.uniform(0, L, M - 1))
    if periodic:
        base = rng.uniform(-0.2, 0.2)
        s0 = np.concatenate([[base], base + inner, [base + L]])
        s1 = s0 + 0.2 * L / M * rng.uniform(-1, 1, M + 1)
        s1[-1] = s1[0] + L
    else:
        s0 = np.concatenate([[0.0], inner, [L]])
        s1 = s0.copy()
        s1[1:-1] += 0.2 * L / M * rng.uniform(-1, 1, M - 1)
    m = 0.03 * rng.uniform(0.5, 1.5, M)
    mbar = np.zeros(M + 1)
    mbar[:-1] += 0.5 * m
    mbar[1:] += 0.5 * m
    common = dict(ds=ds, m=m, mbar=mbar, periodic=periodic)
    mu = None
    if kind == "gas":
        fp = FluidPotential(eos=IdealGas(1.4, 287.0), S=rng.uniform(-50, 50, M), p_ext=0.4, g=GRAV, **common)
    elif kind == "barotropic":
        fp = FluidPotential(eos=Tait(1.0, 1.0, 20.0, 7.0), p_ext=0.4, g=GRAV, **common)
    else:
        V0 = stretched_volumes(s0, R0, np.ones(nR), ds, periodic) * (1 + 0.05 * rng.normal(size=M))
        mu = rng.uniform(0.5, 1.5, M) if kind == "liquid" else np.zeros(M)
        fp = FluidPotential(V0=V0, p_ext=0.0 if kind == "gravity" else 0.4,
                            g=np.zeros(3) if kind == "pext" else GRAV, **common)
    return fp, dict(s0=s0, r0=r0, Lam0=Lam0, R0=R0, s1=s1, r1=r1, Lam1=Lam1, R1=R1, mu=mu)


KINDS = ["gas", "barotropic", "liquid", "pext", "gravity"]


def _vary(st, level, block, j, d, eps):
    """A copy of the state with one variation: r, s, R additive; Lambda -> Lambda cay(eps e_d)."""
    st = {k: (None if v is None else v.copy()) for k, v in st.items()}
    if block == "mu":
        st["mu"][j] += eps
        return st
    key = {"r": "r", "sigma": "Lam", "s": "s", "R": "R"}[block] + str(level)
    if block == "sigma":
        w = np.zeros(3)
        w[d] = eps
        st[key][j] = st[key][j] @ cay(w)
    elif block == "r":
        st[key][j, d] += eps
    else:
        st[key][j] += eps
    return st


def _fd_gradient(fp, st, level, eps=1e-6):
    """Central differences of L in every variation of one level (and in mu): LevelGradient-shaped arrays."""
    def Lval(x):
        return fluid_potential_step(fp, HP, **x).L

    n_nodes, n_lab, nR = len(st["r0"]), len(st["s0"]), len(st["R0"])
    def fd4(b, j, d, e):
        # fourth-order central differences: the sigma forces of a liquid are ~1e-4 of L (they act only
        # through the stretch), below what second-order differences resolve; L is smooth in r and sigma
        f = [Lval(_vary(st, level, b, j, d, k * e)) for k in (-2, -1, 1, 2)]
        return (8 * (f[2] - f[1]) - (f[3] - f[0])) / (12 * e)

    rod = np.zeros((n_nodes, 6))
    for j in range(n_nodes):
        for d in range(3):
            rod[j, d] = fd4("r", j, d, 1e-4)
            rod[j, 3 + d] = fd4("sigma", j, d, 1e-4)
    # a closed tube's end labels stay at 0 and L (varying them would leave the centreline): left at zero
    varied = range(n_lab) if fp.periodic else range(1, n_lab - 1)
    s = np.zeros(n_lab)
    for k in varied:
        s[k] = (Lval(_vary(st, level, "s", k, 0, eps)) - Lval(_vary(st, level, "s", k, 0, -eps))) / (2 * eps)
    R = np.array([(Lval(_vary(st, level, "R", j, 0, eps)) - Lval(_vary(st, level, "R", j, 0, -eps))) / (2 * eps)
                  for j in range(nR)])
    mu = None
    if st["mu"] is not None:
        # L is linear in mu: a large step has no truncation error and less round-off
        mu = np.array([(Lval(_vary(st, level, "mu", k, 0, 0.1)) - Lval(_vary(st, level, "mu", k, 0, -0.1))) / 0.2
                       for k in range(len(st["mu"]))])
    return rod, s, R, mu


def _close(a, b, tol, what):
    scale = np.max(np.abs(b))
    assert scale > 0, f"{what}: the reference is zero (the test would not see the term)"
    err = np.max(np.abs(a - b))
    assert err <= tol * scale, f"{what}: max error {err:.3g} vs scale {scale:.3g}"


#: blocks a term alone leaves exactly zero: gravity acts on positions and labels only (no frames, no
#: radii); the outside pressure on the tube's volume does not depend on where the labels are
ZERO = {"gravity": ("sigma", "R"), "pext": ("s",)}


@pytest.mark.parametrize("periodic", [False, True], ids=["closed", "periodic"])
@pytest.mark.parametrize("kind", KINDS)
def test_potential_gradients_equal_central_differences(kind, periodic):
    fp, st = _case(kind, periodic)
    out = fluid_potential_step(fp, HP, **st)
    sl = slice(None) if periodic else slice(1, -1)  # a closed tube's end labels are not varied
    for level, D in ((0, out.D1), (1, out.D2)):
        rod, s, R, mu = _fd_gradient(fp, st, level)
        # each block on its own scale, so that a term that only moves one block is still seen
        pairs = {"dr": (D.rod[:, :3], rod[:, :3]), "sigma": (D.rod[:, 3:], rod[:, 3:]), "s": (D.s[sl], s[sl]),
                 "R": (D.R, R)}
        for name, (a, b) in pairs.items():
            if name in ZERO.get(kind, ()):
                assert np.max(np.abs(a)) == 0.0 and np.max(np.abs(b)) < 1e-10, name
            else:
                _close(a, b, 1e-7, f"level {level} {name}")
        if mu is not None:
            _close(out.Dmu, mu, 1e-7, "mu")
