"""Exact element derivatives of the rod (varint/terms/rod.py, ``k_element`` and friends; docs/theory.md §9).

The analytic element gradient against the complex step of the whole discrete Lagrangian; the Newton
Jacobian assembled from the element blocks (complex step of the analytic gradient) against central
differences of the residual; the static Hessian (modes, statics) against differences of the force;
and what the finite-difference Hessian of 0.1 got wrong: its noise (5e-9 of the largest entry)
breaks the symmetry and the rigid-motion null space that the exact Hessian keeps to round-off.
"""

import numpy as np
import pytest

from varint import Simulation, build_model
from varint.lattice.lie import cay, cay_inv, dcay_inv
from varint.terms.rod import _k_dcinvT, k_element, banded_jacobian
from varint.model.statics import force_jacobian, force_map

from varint.scene.standard import ROD_SECTION as SECTION, rod_scene, solid_section

LOADS = {"gravity": [0.3, -9.81, 0.5], "load": {"force": [1.0, -2.0, 0.5], "torque": [0.3, 0.2, -0.1]}}
LOADS_2D = {"gravity": [0.3, -9.81, 0.0], "load": {"force": [1.0, -2.0, 0.0], "torque": [0.0, 0.0, -0.1]}}


def _levels(model, rng, amp=0.3):
    """Two nearby lattice levels around the initial state (bent, if the scene's rod is curved)."""
    out = []
    for _ in range(2):
        s = amp * rng.standard_normal((model.N + 1, 3))
        d = amp * model.ds * rng.standard_normal((model.N + 1, 3))
        if model.rod.dim == 2:
            s[:, :2] = 0.0
            d[:, 2] = 0.0
        out.append((model.rod.Lam0 @ cay(s), model.rod.r0 + d))
    return out


def test_dcay_inverse_transpose_kernel_equals_lie_reference():
    rng = np.random.default_rng(0)
    for s in (1.0, -1.0):
        w, v = rng.standard_normal(3), rng.standard_normal(3)
        out = np.empty(3)
        _k_dcinvT(w, v, s, out)
        assert np.allclose(out, dcay_inv(s * w).T @ v, rtol=1e-15, atol=1e-15)


@pytest.mark.parametrize("measure", ["reference", "paper"])
def test_element_kernel_energy_equals_the_numpy_lagrangian(measure):
    """k_element's value is the element piece of RodModel.lagrangian_pieces (the NumPy reference); with the positions
    given relative to a point o and g0 = g . o (as k_rod_gradient centres each element on its first node) its value
    and gradients are the absolute positions' (the paper's measure weights the weight, whose gradient then reads
    where the element is)."""
    model = build_model(rod_scene(measure=measure, gravity=LOADS["gravity"]))
    (L0, r0), (L1, r1) = _levels(model, np.random.default_rng(1))
    r0, r1 = r0 + [3.0, -2.0, 1.5], r1 + [3.0, -2.0, 1.5]
    xi = cay_inv(np.swapaxes(L0, 1, 2) @ L1)
    elem, _ = model.rod.lagrangian_pieces(1e-3, L0, r0, xi, r1)
    _, rhoA, inertia, J, K, g, _ = model.rod._consts()
    for e in (0, 4, model.N - 1):
        D = np.empty((4, 12))
        val, c = k_element(1e-3, model.ds, rhoA, inertia, J, K, g, model.rod.paper_measure, L0[e], L0[e + 1], r0[e],
                           r0[e + 1], xi[e], xi[e + 1], r1[e], r1[e + 1], 0.0, 0, 2, D[0], D[1], np.empty((5, 3, 3)),
                           np.empty((16, 3)))
        assert val == pytest.approx(elem[e], rel=1e-14)
        o = r0[e]
        val_o, c_o = k_element(1e-3, model.ds, rhoA, inertia, J, K, g, model.rod.paper_measure, L0[e], L0[e + 1],
                               r0[e] - o, r0[e + 1] - o, xi[e], xi[e + 1], r1[e] - o, r1[e + 1] - o, float(g @ o), 0, 2,
                               D[2], D[3], np.empty((5, 3, 3)), np.empty((16, 3)))
        assert val_o == pytest.approx(val, rel=1e-13)
        assert c_o == pytest.approx(c, rel=1e-14)
        assert np.abs(D[2:] - D[:2]).max() < 1e-12 * np.abs(D[:2]).max()


@pytest.mark.parametrize("measure", ["reference", "paper"])
def test_the_centred_gradient_sum_is_the_absolute_one(measure):
    """k_rod_gradient (each element centred on its first node with its exact increments: the one sum of the element
    kernels, for RodPart.gradients, the stepper's rod term and the compiled rod step) equals the plain sum of k_element
    over the elements at the absolute positions, far from the origin, with gravity and a tip force, both levels, one
    level alone; and its value is L_d."""
    model = build_model(rod_scene(measure=measure, gravity=LOADS["gravity"], load=LOADS["load"]))
    rod = model.rod
    (L0, r0), (L1, r1) = _levels(model, np.random.default_rng(4))
    r0, r1 = r0 + [30.0, -20.0, 15.0], r1 + [30.0, -20.0, 15.0]
    xi = cay_inv(np.swapaxes(L0, 1, 2) @ L1)
    h = 1e-3
    _, rhoA, inertia, J, K, g, force = rod._consts()
    ref = np.zeros((2, model.N + 1, 6))
    L_ref = 0.5 * h * force @ (r0[-1] + r1[-1])
    e12 = np.empty((2, 12))
    for e in range(model.N):
        val, _ = k_element(h, model.ds, rhoA, inertia, J, K, g, rod.paper_measure, L0[e], L0[e + 1], r0[e], r0[e + 1],
                           xi[e], xi[e + 1], r1[e], r1[e + 1], 0.0, 0, 2, e12[0], e12[1], np.empty((5, 3, 3)),
                           np.empty((16, 3)))
        L_ref += val
        ref[:, e] += e12[:, :6]
        ref[:, e + 1] += e12[:, 6:]
    ref[:, -1, :3] += 0.5 * h * force
    D1, D2, L = rod.gradients(h, L0, r0, xi, r1)
    for D, R in ((D1, ref[0]), (D2, ref[1]), (rod.derivative(h, L0, r0, xi, r1, 1), ref[1])):
        assert np.abs(D - R).max() < 1e-12 * np.abs(R).max()
    assert L == pytest.approx(L_ref, rel=1e-12)
    assert not rod.gradients(h, L0, r0, xi, r1, levels=(0, 1))[1].any()


@pytest.mark.parametrize("measure", ["reference", "paper"])
@pytest.mark.parametrize("dimension", [3, 2])
def test_analytic_gradient_equals_complex_step_of_the_lagrangian(measure, dimension):
    loads = LOADS if dimension == 3 else LOADS_2D
    model = build_model(rod_scene(measure=measure, dimension=dimension, ends=("clamped", "free"), **loads))
    (L0, r0), (L1, r1) = _levels(model, np.random.default_rng(2))
    xi = cay_inv(np.swapaxes(L0, 1, 2) @ L1)
    for h in (1e-3, 1.0):
        D1, D2, _ = model.rod.gradients(h, L0, r0, xi, r1)
        for level, D in ((0, D1), (1, D2)):
            ref = model.rod.derivative_complex_step(h, L0, r0, xi, r1, level)
            assert np.max(np.abs(D - ref)) <= 1e-13 * np.max(np.abs(ref)), (level, np.max(np.abs(D - ref)))


CASES = {
    "3d_clamped_bent_loads": dict(dimension=3, ends=("clamped", "free"), initial={"curvature": [0.5, 1.0, -0.7]}, **LOADS),
    "3d_free_bent_spinning": dict(dimension=3, initial={"curvature": [0.5, 1.0, -0.7], "angular_velocity": [13.0, 40.0, -27.0],
                                                        "velocity": [0.1, 0.2, -0.3]}, gravity=[0.0, 0.0, -9.81]),
    "3d_pinned_paper": dict(dimension=3, ends=("pinned", "free"), measure="paper", **LOADS),
    "2d_clamped_bent_loads": dict(dimension=2, ends=("clamped", "free"), initial={"curvature": [0.0, 0.0, 2.0]}, **LOADS_2D),
    "2d_free_spinning": dict(dimension=2, initial={"angular_velocity": [0.0, 0.0, 30.0]}, gravity=[0.0, -9.81, 0.0]),
}


@pytest.mark.parametrize("case", list(CASES))
def test_assembled_jacobian_equals_finite_differences_of_the_residual(case):
    """Newton's exact Jacobian against the colour-grouped central differences of the residual (the 0.1
    Jacobian), at a state some steps into the motion and at a perturbed iterate."""
    model = build_model(rod_scene(nodes=11, h=1e-2, section=dict(SECTION, axial_stiffness=1e4, shear_stiffness=8e3), **CASES[case]))
    sim = Simulation(model)
    for _ in range(3):
        sim.step()
    N = model.N
    step, q0, p0 = sim.stepper.action, sim.state.q, sim.state.p
    z = sim.stepper.predictor()
    z = z + 0.05 * sim.stepper.scale * np.random.default_rng(3).standard_normal(z.shape)
    J = step.jacobian(q0, z).toarray()
    mask = model.rod.mask

    def full(zz):
        R = np.zeros((N + 1, 6))
        R[mask] = step.residual(q0, p0, zz)
        return R

    Jfd = banded_jacobian(full, z, mask, model.ds).toarray()
    assert np.max(np.abs(J - Jfd)) <= 1e-6 * np.max(np.abs(J)), np.max(np.abs(J - Jfd)) / np.max(np.abs(J))
    # the sparsity is the element stencil: nodes j-1..j+1
    per = int(model.rod.mask[1].sum())
    nodes = np.repeat(np.arange(N + 1), model.rod.mask.sum(1))
    rows, cols = np.nonzero(J)
    assert np.all(np.abs(nodes[rows] - nodes[cols]) <= 1) and per > 0


@pytest.mark.parametrize("case", ["clamped_torque", "spinning_free"])
def test_static_hessian_equals_finite_differences_of_the_force(case):
    """The exact derivative of the generalised force (statics and modes; with the tip torque, and with
    the centrifugal force and torque of a steady rotation) against central differences."""
    if case == "clamped_torque":
        model = build_model(rod_scene(nodes=9, ends=("clamped", "free"), initial={"curvature": [0.5, 1.0, -0.7]}, **LOADS))
        spin, centre = None, None
    else:
        model = build_model(rod_scene(nodes=9, initial={"angular_velocity": [0.0, 0.0, 3.0]}))
        spin, centre = np.array([0.3, 0.2, 3.0]), np.array([0.1, 0.2, 0.3])
    (L, r), _ = _levels(model, np.random.default_rng(4))
    H = force_jacobian(model, L, r, 0.7, spin, centre).toarray()
    Hfd = banded_jacobian(force_map(model, L, r, 0.7, spin, centre), np.zeros(model.nz), model.rod.mask, model.ds).toarray()
    assert np.max(np.abs(H - Hfd)) <= 1e-6 * np.max(np.abs(H)), np.max(np.abs(H - Hfd)) / np.max(np.abs(H))


def test_exact_stiffness_is_symmetric_and_annihilates_rigid_motions_to_round_off():
    """The case the finite-difference Hessian got visibly wrong: a slender free rod (L/r = 10^4).

    At the straight unloaded state the stiffness is symmetric and annihilates the six rigid motions
    (dr = a + w x r, sigma = Lambda^T w).  The 0.1 banded differences left a noise of 5e-9 of the
    largest entry in both (measured here: asymmetry 1.1e-9, rigid residual 1.1e-9; exact: 1.4e-18, 8e-17), which shifts the lowest
    w^2 of a slender cantilever by 3.5e-6 at L/r = 10^4, 4e-4 at 10^5 and 8 % at 10^6 (Rayleigh
    quotients on the exact mode, docs/performance.md); the exact one keeps both to round-off.
    """
    model = build_model(rod_scene(nodes=41, section=solid_section(rad=1e-4)))
    K = -force_jacobian(model, model.rod.Lam0, model.rod.r0).toarray()
    Kfd = -banded_jacobian(force_map(model, model.rod.Lam0, model.rod.r0), np.zeros(model.nz), model.rod.mask, model.ds).toarray()
    big = np.max(np.abs(K))
    rigid = []
    for k in range(3):
        a = np.zeros(3)
        a[k] = 1.0
        rigid.append(np.concatenate([np.tile(a, (model.N + 1, 1)), np.zeros((model.N + 1, 3))], 1))
        rigid.append(np.concatenate([np.cross(a, model.rod.r0), model.rod.Lam0.transpose(0, 2, 1) @ a], 1))
    scale = np.max(np.abs(np.array(rigid)))
    worst = {name: max(np.max(np.abs(M @ v.ravel())) for v in rigid) / (big * scale) for name, M in (("exact", K), ("fd", Kfd))}
    asym = {name: np.max(np.abs(M - M.T)) / big for name, M in (("exact", K), ("fd", Kfd))}
    assert asym["exact"] < 1e-15 and worst["exact"] < 1e-14, (asym, worst)
    assert asym["fd"] > 1e-10 and worst["fd"] > 1e-11, (asym, worst)  # the noise the exact Hessian removes


def test_sparse_modes_of_a_slender_cantilever_against_euler_bernoulli():
    """L/r = 10^4, 100 elements: the lowest w^2 is 1e-15 of the Gershgorin bound on the largest one, so
    the shift-invert solver's first shift (1e-8 of the bound) does not converge and the second
    (1e-14) is taken; the exact stiffness has no noise to shift the modes (the 0.1 differences moved
    w1^2 by 3.5e-6 here, docs/performance.md).  Measured -2.5e-5 and -2.4e-5: the lattice error
    (-2.7e-5 for a thick rod at 100 elements)."""
    from varint.exact.beams import euler_bernoulli_cantilever
    from varint.analysis.rod_modes import rod_modes

    sec = solid_section(rad=1e-4)
    model = build_model(rod_scene(nodes=101, section=sec, ends=("clamped", "free")))
    modes = rod_modes(model, count=4, method="sparse")
    f = np.array([m["frequency"] for m in modes])[::2]  # each bending frequency twice (3D)
    eb = euler_bernoulli_cantilever(sec["bending_stiffness"], sec["mass_per_length"], 1.0, 2)
    assert np.all(np.abs(f / eb - 1) < 5e-5), f / eb - 1
    assert all(m["growth_rate"] == 0.0 for m in modes)


def test_auto_modes_of_a_slender_cantilever_use_the_accurate_solver():
    """method="auto" picks the sparse solver for a rod so slender that the dense solver's round-off
    reaches the lowest frequencies (the dense one reads the first two bending frequencies 1e-2 and 4e-3 off here)."""
    from varint.exact.beams import euler_bernoulli_cantilever
    from varint.analysis.rod_modes import rod_modes

    sec = solid_section(rad=1e-4)
    model = build_model(rod_scene(nodes=101, section=sec, ends=("clamped", "free")))
    f = np.array([m["frequency"] for m in rod_modes(model, count=4)])[::2]
    eb = euler_bernoulli_cantilever(sec["bending_stiffness"], sec["mass_per_length"], 1.0, 2)
    assert np.all(np.abs(f / eb - 1) < 5e-5), f / eb - 1


def test_gradients_return_the_level_they_skip_as_zeros():
    model = build_model(rod_scene(nodes=5, initial={"curvature": [0.3, -0.5, 0.2], "angular_velocity": [1.0, 2.0, -0.5]}))
    rng = np.random.default_rng(5)
    xi = 0.01 * rng.standard_normal((model.N + 1, 3))
    r1 = model.rod.r0 + 1e-3 * rng.standard_normal(model.rod.r0.shape)
    D1, D2, _ = model.rod.gradients(1e-2, model.rod.Lam0, model.rod.r0, xi, r1, levels=(0, 1))
    assert np.all(D2 == 0.0) and np.any(D1 != 0.0)
    D1b, D2b, _ = model.rod.gradients(1e-2, model.rod.Lam0, model.rod.r0, xi, r1, levels=(1, 2))
    assert np.all(D1b == 0.0) and np.any(D2b != 0.0)
    full1, full2, _ = model.rod.gradients(1e-2, model.rod.Lam0, model.rod.r0, xi, r1)
    assert np.array_equal(full1, D1) and np.array_equal(full2, D2b)


@pytest.mark.parametrize("periodic", [False, True])
def test_level_strains_are_the_strain_formulas(periodic):
    """varint.terms.rod.level_strains (the compiled k_element_strains: the one place of the rod's strain formulas, for
    the step's kernels, the fluid's stretch and the energy-momentum step's directors) against the formulas in NumPy:
    Omega = cay^-1(La^T Lb)/ds = 2 a / (c ds), Gamma = (La + Lb)^T (rb - ra)/(2 ds), pa = La^T (rb - ra), pb; real and
    complex batches of any 3 x 3 matrices (directors need not be rotations); a periodic lattice closes with the period."""
    from varint.terms.rod import level_strains

    rng = np.random.default_rng(9)
    n, ds = 6, 0.3
    period = np.array([n * ds, 0.2, -0.1])
    Lam = cay(rng.normal(size=(2, n, 3))) + 0.1 * rng.normal(size=(2, n, 3, 3))
    r = np.cumsum(rng.normal(size=(2, n, 3)) * 0.1 + [ds, 0, 0], 1)
    for L, x in ((Lam, r), (Lam + 1e-30j * rng.normal(size=Lam.shape), r + 1e-30j * rng.normal(size=r.shape))):
        st = level_strains(L, x, ds, periodic, period if periodic else None)
        b = np.arange(n if periodic else n - 1)
        f = (b + 1) % n
        d = x[:, f] - x[:, b] + (np.where(b == n - 1, 1.0, 0.0)[:, None] * period if periodic else 0.0)
        pa = np.einsum("...eki,...ek->...ei", L[:, b], d)
        pb = np.einsum("...eki,...ek->...ei", L[:, f], d)
        R = np.swapaxes(L[:, b], -1, -2) @ L[:, f]
        a = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
        c = 1.0 + np.trace(R, axis1=-2, axis2=-1)
        for got, ref in ((st.pa, pa), (st.pb, pb), (st.Gamma, (pa + pb) / (2 * ds)), (st.a, a), (st.c, c),
                         (st.Omega, 2 * a / (c[..., None] * ds))):
            assert np.abs(got - ref).max() <= 1e-14 * np.abs(ref).max()
            if np.iscomplexobj(x):
                assert np.abs(got.imag - ref.imag).max() <= 1e-13 * np.abs(ref.imag).max()
        if not np.iscomplexobj(x):
            Om = cay_inv(R) / ds
            assert np.abs(st.Omega - Om).max() < 1e-14 * np.abs(Om).max()


@pytest.mark.parametrize("measure", ["reference", "paper"])
def test_the_measure_kernel_is_the_element_kernels(measure):
    """k_measure (the compiled step's closed-form momentum balances) is |Gammabar_e|, k_element's own factor c/(h ds)
    to the bit, at the step's chart (level-n frames and positions, turns xi, increments dr), centred as
    k_rod_gradient centres the element."""
    from varint.terms.rod import k_measure, level_strains

    model = build_model(rod_scene(measure=measure, gravity=LOADS["gravity"]))
    rod = model.rod
    (L0, r0), (L1, r1) = _levels(model, np.random.default_rng(2))
    xi = cay_inv(np.swapaxes(L0, 1, 2) @ L1)
    dr = r1 - r0
    _, rhoA, inertia, J, K, g, _ = rod._consts()
    Gbar = 0.5 * (level_strains(L0, r0, model.ds).Gamma + level_strains(L0 @ cay(xi), r0 + dr, model.ds).Gamma)
    for e in range(model.N):
        mu = k_measure(e, model.ds, L0, r0, xi, dr, np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3)))
        assert mu == pytest.approx(np.linalg.norm(Gbar[e]), rel=1e-14)
        rb0 = r0[e + 1] - r0[e]
        _, c = k_element(1.0, model.ds, rhoA, inertia, J, K, g, True, L0[e], L0[e + 1], np.zeros(3), rb0, xi[e],
                         xi[e + 1], dr[e], rb0 + dr[e + 1], 0.0, 0, 2, np.empty(12), np.empty(12), np.empty((5, 3, 3)),
                         np.empty((16, 3)))
        assert c == 1.0 * model.ds * mu
