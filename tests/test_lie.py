"""SO(3) Cayley utilities: group identities, derivatives against finite differences, kernels = references."""

import numpy as np
import pytest

from varint.lattice import lie

RNG = np.random.default_rng(11)
W = RNG.standard_normal((20, 3)) * 1.5


def test_hat_vee_roundtrip_and_cross_product():
    v = RNG.standard_normal((20, 3))
    assert np.allclose(lie.vee(lie.hat(W)), W)
    assert np.allclose(np.einsum("nij,nj->ni", lie.hat(W), v), np.cross(W, v))


def test_cay_is_a_rotation_and_matches_the_rational_form():
    C = lie.cay(W)
    assert lie.orthogonality_error(C) < 1e-14
    assert np.allclose(np.linalg.det(C), 1.0)
    Wh = lie.hat(W)
    ref = np.linalg.solve(np.eye(3) - 0.5 * Wh, np.eye(3) + 0.5 * Wh)
    assert np.allclose(C, ref, atol=1e-14)


def test_cay_inverse_and_group_identities():
    assert np.allclose(lie.cay_inv(lie.cay(W)), W, atol=1e-12)
    assert np.allclose(lie.cay(-W), np.swapaxes(lie.cay(W), -1, -2), atol=1e-15)
    assert np.allclose(lie.cay_inv(np.swapaxes(lie.cay(W), -1, -2)), -W, atol=1e-12)


def test_half_squares_to_the_full_rotation():
    H = lie.cay(lie.half(W))
    assert np.allclose(H @ H, lie.cay(W), atol=1e-14)


def _fd_right_trivialised(w, dw, e=1e-6):
    dC = (lie.cay(w + e * dw) - lie.cay(w - e * dw)) / (2 * e)
    return lie.vee(dC @ lie.cay(w).T), lie.vee(lie.cay(w).T @ dC)


@pytest.mark.parametrize("i", range(5))
def test_dcay_against_finite_differences(i):
    w, dw = W[i], RNG.standard_normal(3)
    right, left = _fd_right_trivialised(w, dw)
    assert np.allclose(lie.dcay(w) @ dw, right, atol=1e-9)
    assert np.allclose(lie.dcay(-w) @ dw, left, atol=1e-9)
    assert np.allclose(lie.dcay_inv(w) @ lie.dcay(w), np.eye(3), atol=1e-14)


def test_kernels_equal_references():
    out = np.empty((len(W), 3, 3))
    lie.cay_batch(W, out)
    assert np.allclose(out, lie.cay(W), atol=1e-15)
    v = np.empty((len(W), 3))
    lie.cay_inv_batch(out, v)
    assert np.allclose(v, lie.cay_inv(out), atol=1e-13)
    out2 = np.empty_like(out)
    lie.cay_batch.py_func(W, out2)
    assert np.array_equal(out, out2) or np.allclose(out, out2, atol=1e-16)


def test_hat_kernel_equals_hat():
    """The compiled k_hat (the kernels' hat map) is hat, to the bit, on real and complex vectors."""
    for w in (W, W + 1j * RNG.standard_normal(W.shape)):
        out = np.empty((len(w), 3, 3), dtype=w.dtype)
        for i in range(len(w)):
            lie.k_hat(w[i], 0.7, out[i])
        assert np.array_equal(out, 0.7 * lie.hat(w))
        assert np.array_equal(out[:, 0, 1:], 0.7 * np.stack([-w[:, 2], w[:, 1]], -1))
