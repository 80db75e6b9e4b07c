"""The coupled tube's fluid step terms (docs/theory.md §10.4, §10.5) against independent references.

Kinetic term: finite differences of its own action, its symmetries (the Noether momenta of §10.6), the
straight tube.  Potential term (internal energy or volume constraint, external pressure, gravity), each
term alone and all together, ideal gas / barotropic / incompressible, closed and periodic: level
gradients against central differences of L (Lie variations Lambda cay(eps e_d) for the frames), the
Newton blocks of both terms against differences of the rotated residual in the step unknowns, rigid-motion
invariance and the level-wise identities of §10.6, and the 0.1 tube terms on the fixed straight
centreline (varint/terms/tube_potential.py through the model's tube part)."""

import math

import numpy as np
import pytest

from varint.terms.coupled import fluid_kinetic_step

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
    from varint.lattice.centreline import centreline

    X0, X1 = centreline(s0, r0, ds)[0], centreline(s1, r1, ds)[0]
    P = np.sum(mbar[:, None] * (X1 - X0), axis=0) / H
    assert np.allclose(f1.sum(0), P, rtol=1e-13, atol=0)


# ---------------------------------------------------------------------------
# the fluid's potential part of the step (docs/theory.md §10.4.2) and both terms in the stepper's layout

from varint.lattice.centreline import centreline, nodal_stretch, stretched_volumes  # noqa: E402
from varint.terms.coupled import (FluidPotential, element_strains, fluid_kinetic_chart, fluid_potential_step, newton_offsets, stretch_map)
from varint.lattice.lie import cay, cay_inv  # noqa: E402
from varint.terms.thermo import IdealGas, Tait  # noqa: E402

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
        rho0 = float(np.mean(m / stretched_volumes(s0, R0, np.ones(nR), ds, periodic)))
        fp = FluidPotential(eos=Tait(rho0, 1.0, 20.0, 7.0), p_ext=0.4, g=GRAV, **common)
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


def _chart_state(st, u, n_nodes, n_lab, nR, n_mu):
    """The state with level n+1 given by the step unknowns u in the Newton ordering:
    r^{n+1} = r^n + Lambda^n b, Lambda^{n+1} = Lambda^n cay(xi), s^{n+1}, R^{n+1}, mu."""
    off, _ = newton_offsets(n_nodes, n_lab, nR, n_mu)
    rod = u[:6 * n_nodes].reshape(n_nodes, 6)
    x = dict(st)
    x["r1"] = st["r0"] + np.einsum("nij,nj->ni", st["Lam0"], rod[:, :3])
    x["Lam1"] = st["Lam0"] @ cay(rod[:, 3:])
    x["s1"] = u[off["s"]:off["R"]].copy()
    x["R1"] = u[off["R"]:off["mu"]].copy()
    x["mu"] = u[off["mu"]:].copy() if n_mu else None
    return x


def _chart_unknowns(st, n_nodes, n_mu):
    rod = np.zeros((n_nodes, 6))
    rod[:, :3] = np.einsum("nji,nj->ni", st["Lam0"], st["r1"] - st["r0"])
    rod[:, 3:] = cay_inv(np.einsum("nji,njk->nik", st["Lam0"], st["Lam1"]))
    return np.concatenate([rod.ravel(), st["s1"], st["R1"], st["mu"] if n_mu else []])


def _residual_rows(out, Lam0, n_mu):
    """[rod (translations rotated to the level-n body frame) | s | R | mu] of D1 and D_mu."""
    rod = out.D1.rod.copy()
    rod[:, :3] = np.einsum("nji,nj->ni", Lam0, rod[:, :3])
    return np.concatenate([rod.ravel(), out.D1.s, out.D1.R, out.Dmu if n_mu else []])


def _dense_coo(block, n):
    J = np.zeros((n, n))
    np.add.at(J, (block[0], block[1]), block[2])
    return J


def _jacobian_fd(F, u, skip, eps):
    """Fourth-order central differences of F in every unknown not in ``skip`` (columns left zero there)."""
    cols = []
    for i in range(len(u)):
        if i in skip:
            cols.append(np.zeros_like(F(u)))
            continue
        f = []
        for k in (-2, -1, 1, 2):
            x = u.copy()
            x[i] += k * eps[i]
            f.append(F(x))
        cols.append((8 * (f[2] - f[1]) - (f[3] - f[0])) / (12 * eps[i]))
    return np.stack(cols, axis=1)


@pytest.mark.parametrize("periodic", [False, True], ids=["closed", "periodic"])
@pytest.mark.parametrize("kind", KINDS)
def test_potential_newton_block_equals_differences_of_the_residual(kind, periodic):
    fp, st = _case(kind, periodic)
    n_nodes, n_lab, nR = len(st["r0"]), len(st["s0"]), len(st["R0"])
    n_mu = 0 if st["mu"] is None else len(st["mu"])
    off, n = newton_offsets(n_nodes, n_lab, nR, n_mu)
    u = _chart_unknowns(st, n_nodes, n_mu)
    out = fluid_potential_step(fp, HP, **st, newton=True)
    J = _dense_coo(out.newton, n)

    def F(x):
        return _residual_rows(fluid_potential_step(fp, HP, **_chart_state(st, x, n_nodes, n_lab, nR, n_mu)),
                              st["Lam0"], n_mu)

    assert np.allclose(F(u), _residual_rows(out, st["Lam0"], n_mu), rtol=1e-13, atol=1e-18)
    # labels: small steps (C^1 only across nodes); the rest is smooth; a closed tube's end labels stay
    eps = np.full(n, 1e-4)
    eps[off["s"]:off["R"]] = 1e-6
    eps[off["mu"]:] = 1e-2
    skip = set() if periodic else {off["s"], off["R"] - 1}
    J_fd = _jacobian_fd(F, u, skip, eps)
    keep = np.ones(n, bool)
    keep[list(skip)] = False
    J, J_fd = J[keep][:, keep], J_fd[keep][:, keep]
    # block by block, each on its own scale: [rod | s | R | mu] rows x columns
    edges = [0, off["s"], off["R"], off["mu"], n]
    edges = [e - sum(1 for i in skip if i < e) for e in edges]
    names = ["rod", "s", "R", "mu"]
    seen = 0
    for a in range(4):
        for b in range(4):
            blk, ref = J[edges[a]:edges[a + 1], edges[b]:edges[b + 1]], J_fd[edges[a]:edges[a + 1], edges[b]:edges[b + 1]]
            if ref.size == 0:
                continue
            scale = np.max(np.abs(ref))
            if scale < 1e-9 * np.max(np.abs(J_fd)):
                assert np.max(np.abs(blk)) <= 1e-9 * np.max(np.abs(J_fd)), f"{names[a]} x {names[b]}"
                continue
            seen += 1
            err = np.max(np.abs(blk - ref))
            assert err <= 1e-7 * scale, f"{names[a]} x {names[b]}: {err:.3g} vs {scale:.3g}"
    assert seen >= 3


@pytest.mark.parametrize("periodic", [False, True], ids=["closed", "periodic"])
def test_kinetic_chart_gradients_and_newton_block(periodic):
    fp, st = _case("gas", periodic)
    n_nodes, n_lab = len(st["r0"]), len(st["s0"])
    args = dict(mbar=fp.mbar, h=HP, ds=fp.ds, periodic=periodic)

    def Lval(x):
        return fluid_kinetic_step(x["s0"], x["r0"], x["s1"], x["r1"], **args)[0]

    out = fluid_kinetic_chart(st["s0"], st["r0"], st["Lam0"], st["s1"], st["r1"], newton=True, **args)
    assert out.L == pytest.approx(Lval(st), rel=1e-15)
    varied = range(n_lab) if periodic else range(1, n_lab - 1)
    for level, D in ((0, out.D1), (1, out.D2)):
        assert np.all(D.rod[:, 3:] == 0.0)  # positions only: no frame forces
        eps = 1e-6
        fd = np.zeros((n_nodes, 3))
        for j in range(n_nodes):
            for d in range(3):
                fd[j, d] = (Lval(_vary(st, level, "r", j, d, eps)) - Lval(_vary(st, level, "r", j, d, -eps))) / (2 * eps)
        _close(D.rod[:, :3], fd, 1e-7, f"level {level} dr")
        fs = np.array([(Lval(_vary(st, level, "s", k, 0, eps)) - Lval(_vary(st, level, "s", k, 0, -eps))) / (2 * eps)
                       for k in varied])
        _close(D.s[list(varied)], fs, 1e-7, f"level {level} s")

    off, n = newton_offsets(n_nodes, n_lab, 0, 0)
    u = _chart_unknowns(st, n_nodes, 0)[:n]

    def F(x):
        y = _chart_state(st, np.concatenate([x, []]), n_nodes, n_lab, 0, 0)
        o = fluid_kinetic_chart(y["s0"], y["r0"], y["Lam0"], y["s1"], y["r1"], **args)
        return _residual_rows(o, st["Lam0"], 0)

    skip = set() if periodic else {off["s"], n - 1}
    eps = np.full(n, 1e-4)
    eps[off["s"]:] = 1e-6
    J = _dense_coo(out.newton, n)
    J_fd = _jacobian_fd(F, u, skip, eps)
    keep = [i for i in range(n) if i not in skip]
    _close(J[np.ix_(keep, keep)], J_fd[np.ix_(keep, keep)], 1e-8, "kinetic Newton block")
    assert not np.any(J[:, :off["s"]].reshape(n, n_nodes, 6)[:, :, 3:])  # no xi columns


def _rigid(st, Q, c):
    x = dict(st)
    for lev in "01":
        x["r" + lev] = st["r" + lev] @ Q.T + c
        x["Lam" + lev] = Q[None] @ st["Lam" + lev]
    return x


@pytest.mark.parametrize("kind", ["gas", "barotropic", "liquid"])
def test_potential_is_invariant_under_rigid_motions(kind):
    fp, st = _case(kind)
    fp = FluidPotential(**{**fp.__dict__, "g": np.zeros(3)})
    Q = cay(np.array([0.7, -1.1, 0.4]))
    L = fluid_potential_step(fp, HP, **st).L
    moved = fluid_potential_step(fp, HP, **_rigid(st, Q, np.array([3.0, -1.0, 2.0]))).L
    assert moved == pytest.approx(L, rel=1e-13)


@pytest.mark.parametrize("kind", ["gas", "liquid"])
def test_levelwise_noether_identities(kind):
    """§10.6: every internal term is invariant under a rigid motion of one level alone, so the level's
    forces add up to gravity's share (h/2) M_fluid g and their moment to (h/2) sum_k mbar_k X(sbar_k; r^l) x g."""
    fp, st = _case(kind)
    out = fluid_potential_step(fp, HP, **st)
    sbar = 0.5 * (st["s0"] + st["s1"])
    for lev, D in (("0", out.D1), ("1", out.D2)):
        r, Lam = st["r" + lev], st["Lam" + lev]
        force = D.rod[:, :3].sum(0)
        scale = np.max(np.abs(D.rod))
        assert np.max(np.abs(force - 0.5 * HP * fp.mbar.sum() * GRAV)) < 1e-14 * scale * len(r)
        X = centreline(sbar, r, fp.ds)[0]
        torque = np.cross(r, D.rod[:, :3]).sum(0) + np.einsum("nij,nj->i", Lam, D.rod[:, 3:])
        expected = 0.5 * HP * np.cross(np.sum(fp.mbar[:, None] * X, axis=0), GRAV)
        assert np.max(np.abs(torque - expected)) < 1e-14 * scale * len(r)


# -- reduction to 0.1 on the fixed straight centreline (docs/theory.md §10.8)

LIQUID = {"model": "incompressible", "density": 1000.0, "pressure": 1.0e5}


@pytest.mark.parametrize("fluid,ends", [("gas", "closed"), ("gas", "periodic"), ("liquid", "closed")])
def test_straight_fixed_centreline_reduces_to_the_tube_terms(fluid, ends):
    from varint.scene.standard import gas_scene
    from helpers import make
    from varint.terms.tube_potential import Config

    d = gas_scene(nodes=9, parcels=11, ends=ends, environment={"external_pressure": 9.0e4, "gravity": [7.5, 0.0, 0.0]})
    if fluid == "liquid":
        d["fluid"] = dict(LIQUID, parcels=11, ends={"s0": ends, "sL": ends})
    scene, model = make(d)
    model = getattr(model, "tube", None) or model  # the one model keeps the 0.1 tube as its tube part
    rng = np.random.default_rng(5)
    periodic, M, nR, ds, L = model.periodic, model.M, model.nR, model.ds, model.L
    n_nodes = nR
    straight = np.zeros((n_nodes, 3))
    straight[:, 0] = np.arange(n_nodes) * ds
    frames = np.broadcast_to(np.eye(3), (n_nodes, 3, 3)).copy()
    s0 = np.linspace(0.0, L, M + 1)
    s0[1:-1] += 0.3 * L / M * rng.uniform(-1, 1, M - 1)
    s1 = s0.copy()
    s1[1:-1] += 0.1 * L / M * rng.uniform(-1, 1, M - 1)
    R0 = model.R0 * (1 + 0.05 * rng.uniform(-1, 1, nR))
    R1 = R0 * (1 + 0.01 * rng.normal(size=nR))
    mu = 1.0e5 * (1 + 0.1 * rng.normal(size=M)) if model.incompressible else None
    mbar = 0.5 * (np.concatenate([model.m, [0.0]]) + np.concatenate([[0.0], model.m]))
    if periodic:  # label M is label 0 shifted by L: its mass is counted once, at label 0
        mbar[0], mbar[-1] = 0.5 * (model.m[0] + model.m[-1]), 0.0
    fp = FluidPotential(ds=ds, m=model.m, mbar=mbar, eos=model.eos, S=model.S,
                        V0=model.V0 if model.incompressible else None, p_ext=model.p_ext,
                        g=np.array([model.gx, 0.0, 0.0]), periodic=periodic)
    out = fluid_potential_step(fp, HP, s0, straight, frames, R0, s1, straight, frames, R1, mu)

    # 0.1: the potential's gradient at the midpoint configuration, without the wall's own elastic term
    cfg = Config(0.5 * (s0 + s1), 0.5 * (R0 + R1), mu)
    grad = model.gradient(cfg)
    U = model.potential(cfg)
    wall = [t for t in model.terms if t.name == "wall_elastic"]
    fluid_term = "incompressibility" if fluid == "liquid" else "internal"
    assert len(wall) == 1
    assert {t.name for t in model.terms} - {"wall_elastic"} == {fluid_term, "external_pressure", "gravity"}
    gs, gR, gmu = np.zeros(M + 1), np.zeros(nR), np.zeros(M if mu is not None else 0)
    wall[0].gradient(cfg, {}, gs, gR, gmu)
    U -= wall[0].energy(cfg, {})
    i = model.index
    g_s, g_R = grad[:i["R"]], grad[i["R"]:i["R"] + nR] - gR
    interior = slice(0, M) if periodic else slice(1, M)
    for D in (out.D1, out.D2):
        assert np.allclose(D.s[interior], -0.5 * HP * g_s[interior], rtol=1e-12, atol=1e-12 * np.max(np.abs(D.s)))
        assert np.allclose(D.R, -0.5 * HP * g_R, rtol=1e-12, atol=1e-12 * np.max(np.abs(D.R)))
    if mu is not None:
        assert np.allclose(out.Dmu, -HP * grad[i["mu"]:], rtol=1e-10, atol=1e-12 * np.max(np.abs(out.Dmu)))
    # values: 0.1 leaves the fixed end labels out of gravity (a constant); here they carry mbar_0, mbar_M
    ends_term = 0.0 if periodic else model.gx * mbar[-1] * L
    assert out.L == pytest.approx(-HP * (U - ends_term), rel=1e-12)


# -- the small pieces the term is built from


@pytest.mark.parametrize("periodic", [False, True], ids=["closed", "periodic"])
def test_stretch_map_and_element_strains(periodic):
    ds, Lam, r, _, _ = _rod(periodic, 7, 1.2, 9)
    n = len(r)
    G = np.random.default_rng(1).uniform(0.8, 1.2, n if periodic else n - 1)
    assert np.allclose(stretch_map(n, periodic) @ G, nodal_stretch(G, periodic), rtol=1e-15, atol=0)
    Gam, pa, pb = element_strains(Lam, r, ds, periodic)
    for e in range(len(Gam)):  # one element at a time, the periodic closing element with r_N = r_0 + L e_1
        b = (e + 1) % n
        chord = r[b] - r[e] + (np.array([1.2, 0, 0]) if b < e + 1 else 0.0)
        assert np.allclose(Gam[e], 0.5 * (Lam[e] + Lam[b]).T @ chord / ds, rtol=1e-14, atol=1e-15)
        assert np.allclose(pa[e], Lam[e].T @ chord, rtol=1e-14, atol=1e-15)


@pytest.mark.parametrize("periodic", [False, True], ids=["closed", "periodic"])
def test_external_pressure_works_on_the_whole_stretched_volume(periodic):
    """L of p_ext alone is -h p_ext Vol(Rbar, gamma) with Vol the sum of the parcel volumes over the whole
    tube (varint/lattice/centreline.py, checked there against quadrature)."""
    fp, st = _case("pext", periodic)
    fp = FluidPotential(**{**fp.__dict__, "g": np.zeros(3)})
    out = fluid_potential_step(fp, HP, **st)
    G0 = element_strains(st["Lam0"], st["r0"], fp.ds, periodic)[0]
    G1 = element_strains(st["Lam1"], st["r1"], fp.ds, periodic)[0]
    gamma = nodal_stretch(np.linalg.norm(0.5 * (G0 + G1), axis=1), periodic)
    Rbar = 0.5 * (st["R0"] + st["R1"])
    ends = np.array([0.3, 0.3 + 1.2]) if periodic else np.array([0.0, 1.2])
    Vol = stretched_volumes(ends, Rbar, gamma, fp.ds, periodic)[0]
    assert out.L == pytest.approx(-HP * fp.p_ext * Vol, rel=1e-13)


# -- the compiled kernels against the NumPy/scipy reference path (fast=False) and scipy's sparse algebra

import scipy.sparse as sps  # noqa: E402

from varint.terms import coupled as ct  # noqa: E402


#: (elements, parcels, seed of `_case`): seeds whose moved labels stay ordered and on the tube
SIZES = [(7, 9, 3), (12, 3, 5), (4, 17, 3)]


def _same_step_term(a, b, n, rtol=1e-12):
    """Two StepTerms equal to round-off: every block on its own scale, the Newton blocks as dense matrices."""
    assert a.L == pytest.approx(b.L, rel=rtol)
    for lev in ("D1", "D2"):
        for f in ("rod", "s", "R"):
            x, y = getattr(getattr(a, lev), f), getattr(getattr(b, lev), f)
            assert x.shape == y.shape
            assert np.max(np.abs(x - y), initial=0.0) <= rtol * np.max(np.abs(y), initial=0.0), (lev, f)
    assert (a.Dmu is None) == (b.Dmu is None)
    if b.Dmu is not None:
        assert np.max(np.abs(a.Dmu - b.Dmu)) <= rtol * np.max(np.abs(b.Dmu))
    assert (a.newton is None) == (b.newton is None)
    if b.newton is not None:
        Ja, Jb = _dense_coo(a.newton, n), _dense_coo(b.newton, n)
        assert np.max(np.abs(Ja - Jb)) <= rtol * np.max(np.abs(Jb))


@pytest.mark.parametrize("periodic", [False, True], ids=["closed", "periodic"])
@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("sizes", SIZES, ids=["M~N", "long-parcels", "short-parcels"])
def test_compiled_potential_equals_the_numpy_reference(kind, periodic, sizes):
    """Parcels over one or two elements, over several (a parcel's stencil reaches 5 elements), and several
    parcels per element; gradient path and Newton block."""
    n_el, M, seed = sizes
    fp, st = _case(kind, periodic, n_el=n_el, M=M, seed=seed)
    n_nodes, n_lab, nR = len(st["r0"]), len(st["s0"]), len(st["R0"])
    n = newton_offsets(n_nodes, n_lab, nR, 0 if st["mu"] is None else M)[1]
    for newton in (False, True):
        fast = fluid_potential_step(fp, HP, **st, newton=newton)
        ref = fluid_potential_step(fp, HP, **st, newton=newton, fast=False)
        _same_step_term(fast, ref, n)


@pytest.mark.parametrize("periodic", [False, True], ids=["closed", "periodic"])
@pytest.mark.parametrize("sizes", SIZES, ids=["M~N", "long-parcels", "short-parcels"])
def test_compiled_kinetic_chart_equals_the_numpy_reference(periodic, sizes):
    fp, st = _case("gas", periodic, n_el=sizes[0], M=sizes[1], seed=sizes[2])
    args = dict(mbar=fp.mbar, h=HP, ds=fp.ds, periodic=periodic)
    n = 6 * len(st["r0"]) + len(st["s0"])
    for newton in (False, True):
        fast = fluid_kinetic_chart(st["s0"], st["r0"], st["Lam0"], st["s1"], st["r1"], newton=newton, **args)
        ref = fluid_kinetic_chart(st["s0"], st["r0"], st["Lam0"], st["s1"], st["r1"], newton=newton, fast=False, **args)
        _same_step_term(fast, ref, n)


def _random_coo(rng, n_rows, n_cols, nnz):
    """COO triplets with repeated (row, col) pairs and a few exact zeros."""
    rows = rng.integers(0, n_rows, nnz)
    cols = rng.integers(0, n_cols, nnz)
    vals = rng.normal(size=nnz)
    vals[::7] = 0.0
    rows[1::5] = rows[::5][:len(rows[1::5])]   # duplicates
    cols[1::5] = cols[::5][:len(cols[1::5])]
    return rows.astype(np.int64), cols.astype(np.int64), vals


def _csr_dense(p, i, x, n_cols):
    out = np.zeros((len(p) - 1, n_cols))
    for r in range(len(p) - 1):
        np.add.at(out[r], i[p[r]:p[r + 1]], x[p[r]:p[r + 1]])
    return out


def test_sparse_kernels_equal_scipy():
    """The CSR helpers of the Newton kernel: the counting-sort conversion keeps every triplet, the duplicate
    sum (with and without dropping zeros) leaves each (row, column) once and the same matrix, and the
    marker-array product equals scipy's, each column once per row."""
    rng = np.random.default_rng(4)
    A = _random_coo(rng, 13, 17, 80)
    B = _random_coo(rng, 17, 11, 90)
    Ad = sps.coo_matrix((A[2], (A[0], A[1])), shape=(13, 17)).toarray()
    Bd = sps.coo_matrix((B[2], (B[0], B[1])), shape=(17, 11)).toarray()
    Ap, Ai, Ax = ct._k_coo_to_csr(*A, 13)
    assert len(Ai) == len(A[0]) and np.array_equal(_csr_dense(Ap, Ai, Ax, 17), Ad)
    for drop in (False, True):
        Sp, Si, Sx = ct._k_csr_sum_duplicates(Ap, Ai, Ax, 17, drop)
        assert np.allclose(_csr_dense(Sp, Si, Sx, 17), Ad, rtol=1e-15, atol=1e-15)
        for r in range(13):
            row = Si[Sp[r]:Sp[r + 1]]
            assert len(set(row)) == len(row)
            if drop:
                assert np.all(Sx[Sp[r]:Sp[r + 1]] != 0.0)
    assert len(ct._k_csr_sum_duplicates(Ap, Ai, Ax, 17, True)[1]) == np.count_nonzero(Ad)
    Bp, Bi, Bx = ct._k_coo_to_csr(*B, 17)
    Cp, Ci, Cx = ct._k_spgemm(Ap, Ai, Ax, Bp, Bi, Bx, 11)
    assert np.allclose(_csr_dense(Cp, Ci, Cx, 11), Ad @ Bd, rtol=1e-14, atol=1e-14)
    for r in range(13):
        assert len(set(Ci[Cp[r]:Cp[r + 1]])) == Cp[r + 1] - Cp[r]


@pytest.mark.parametrize("what", ["nan", "beyond-the-end", "out-of-order"])
def test_labels_the_kernels_cannot_read_give_the_reference_errors(what):
    """The compiled path checks labels before reading them and hands the call to the NumPy path, which
    raises the precise error: both paths fail alike."""
    fp, st = _case("gas")
    L = st["s0"][-1]
    if what == "nan":
        st["s1"][3] = np.nan
    elif what == "beyond-the-end":
        st["s0"][-1] = st["s1"][-1] = 1.1 * L
    else:
        st["s0"][3], st["s0"][4] = st["s0"][4], st["s0"][3]
        st["s1"][3], st["s1"][4] = st["s1"][4], st["s1"][3]
    errors = []
    for fast in (True, False):
        with pytest.raises(ValueError) as info:
            fluid_potential_step(fp, HP, **st, newton=True, fast=fast)
        errors.append(str(info.value))
    assert errors[0] == errors[1]
    if what != "out-of-order":  # the kinetic term reads each label on its own: order does not matter to it
        args = dict(mbar=fp.mbar, h=HP, ds=fp.ds)
        errors = []
        for fast in (True, False):
            with pytest.raises(ValueError) as info:
                fluid_kinetic_chart(st["s0"], st["r0"], st["Lam0"], st["s1"], st["r1"], fast=fast, **args)
            errors.append(str(info.value))
        assert errors[0] == errors[1]
