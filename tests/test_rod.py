"""The Cayley-map rod: action gradient with Lie-group variations, conservation, loads, waves, modes, statics."""

import math

import numpy as np
import pytest

from varint import build_model, parse_scene
from varint.lie import cay, cay_inv
from varint.rod import RodSimulation, rod_modes, static_equilibrium

from helpers import to_toml

SECTION = {"mass_per_length": 0.3, "rotary_inertia": 1e-4, "bending_stiffness": 2.0, "torsional_stiffness": 1.5,
           "axial_stiffness": 1e3, "shear_stiffness": 8e2}


def rod_scene(nodes=11, h=1e-3, ends=("free", "free"), initial=None, load=None, gravity=None, dimension=3,
              measure="paper", section=None, length=1.0, end=1.0):
    rod = dict(section or SECTION, dimension=dimension, measure=measure, ends={"s0": ends[0], "sL": ends[1]})
    if initial:
        rod["initial"] = initial
    if load:
        rod["load"] = load
    d = {"title": "rod", "tube": {"length": length, "nodes": nodes, "radius": 0.01}, "rod": rod,
         "time": {"step": h, "end": end}}
    if gravity:
        d["environment"] = {"gravity": gravity}
    return parse_scene(to_toml(d))


TUMBLE = {"velocity": [0.1, 0.2, -0.3], "angular_velocity": [1.0, 3.0, -2.0], "curvature": [0.5, 1.0, -0.7]}


def _random_levels(model, rng, amp=0.05):  # noqa: D401
    """Three nearby lattice configurations (Lambda, r) around the initial one."""
    out = []
    for _ in range(3):
        Lam = model.Lam0 @ cay(amp * rng.standard_normal((model.N + 1, 3)))
        r = model.r0 + amp * model.ds * rng.standard_normal((model.N + 1, 3))
        out.append((Lam, r))
    return out


@pytest.mark.parametrize("measure", ["paper", "reference"])
@pytest.mark.parametrize("extras", ["plain", "gravity+force"])
def test_step_residual_is_gradient_of_action_with_lie_variations(measure, extras):
    kw = {"gravity": [0.3, -9.81, 0.5], "load": {"force": [1.0, -2.0, 0.5]}} if extras != "plain" else {}
    model = build_model(rod_scene(measure=measure, ends=("clamped", "free"), **kw))
    h = 1e-3
    rng = np.random.default_rng(3)
    (L0, r0), (L1, r1), (L2, r2) = _random_levels(model, rng)

    def action(sig, dr):
        La = L1 @ cay(sig)
        ra = r1 + dr
        xi_a = cay_inv(np.swapaxes(L0, 1, 2) @ La)
        xi_b = cay_inv(np.swapaxes(La, 1, 2) @ L2)
        s = 0.0
        for (Ln, rn, xi, r_1) in ((L0, r0, xi_a, ra), (La, ra, xi_b, r2)):
            e, n = model.lagrangian_pieces(h, Ln, rn, xi, r_1)
            s += e.sum() + n.sum()
        return s

    xi01 = cay_inv(np.swapaxes(L0, 1, 2) @ L1)
    xi12 = cay_inv(np.swapaxes(L1, 1, 2) @ L2)
    grad = model.derivative(h, L0, r0, xi01, r1, level=1) + model.derivative(h, L1, r1, xi12, r2, level=0)
    zero = np.zeros((model.N + 1, 3))
    fd = np.zeros_like(grad)
    for j in range(model.N + 1):
        for d in range(6):
            e = 1e-6
            sp, dp = zero.copy(), zero.copy()
            (dp if d < 3 else sp)[j, d % 3] = e
            fd[j, d] = (action(sp, dp) - action(-sp, -dp)) / (2 * e)
    assert np.allclose(grad, fd, atol=1e-6 * np.abs(fd).max()), np.abs(grad - fd).max()


STIFF = dict(SECTION, axial_stiffness=1e4, shear_stiffness=8e3)


def test_free_tumbling_rod_conserves_momenta_energy_and_orthogonality():
    """Spin about an oblique axis (h |omega| = 0.5 per step): the rod flexes under centrifugal loads.

    Momenta to round-off, energy bounded, frames orthogonal.  (A free rod with uniform initial
    curvature is not admissible data: its free ends carry an unbalanced moment.)
    """
    model = build_model(rod_scene(nodes=11, h=1e-2, section=STIFF,
                                  initial={"velocity": [0.1, 0.2, -0.3], "angular_velocity": [13.0, 40.0, -27.0]}))
    sim = RodSimulation(model)
    sim.step()
    m1 = sim.monitors()
    P, J, E = m1["linear_momentum"], m1["angular_momentum"], m1["energy"]
    worst = {"P": 0.0, "J": 0.0, "E": 0.0, "orth": 0.0}
    xi_max = 0.0
    for _ in range(400):
        sim.step()
        mo = sim.monitors()
        xi_max = max(xi_max, np.max(np.linalg.norm(sim.state.v[3 * (model.N + 1):].reshape(-1, 3), axis=1)))
        worst["P"] = max(worst["P"], np.max(np.abs(mo["linear_momentum"] - P)) / np.linalg.norm(P))
        worst["J"] = max(worst["J"], np.max(np.abs(mo["angular_momentum"] - J)) / np.linalg.norm(J))
        worst["E"] = max(worst["E"], abs(mo["energy"] - E) / E)
        worst["orth"] = max(worst["orth"], mo["frame_orthogonality"])
    assert xi_max > 0.45  # genuinely large rotations per step
    assert worst["P"] < 1e-12 and worst["J"] < 1e-12, worst
    assert worst["orth"] < 1e-13, worst
    assert worst["E"] < 0.05, worst
