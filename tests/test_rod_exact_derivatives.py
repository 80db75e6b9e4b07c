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
from varint.terms.rod import EPS_CS, _k_dcinvT, k_element, banded_jacobian
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
    """k_element's value is the element piece of RodModel.lagrangian_pieces (the NumPy reference)."""
    model = build_model(rod_scene(measure=measure, gravity=LOADS["gravity"]))
    (L0, r0), (L1, r1) = _levels(model, np.random.default_rng(1))
    xi = cay_inv(np.swapaxes(L0, 1, 2) @ L1)
    elem, _ = model.rod.lagrangian_pieces(1e-3, L0, r0, xi, r1)
    _, rhoA, inertia, J, K, g, _ = model.rod._consts()
    for e in (0, 4, model.N - 1):
        val = k_element(1e-3, model.ds, rhoA, inertia, J, K, g, model.rod.paper_measure, L0[e], L0[e + 1], r0[e], r0[e + 1],
                         xi[e], xi[e + 1], r1[e], r1[e + 1], 0, 2, np.empty(12), np.empty(12), np.empty((5, 3, 3)),
                         np.empty((16, 3)))
        assert val == pytest.approx(elem[e], rel=1e-14)


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
