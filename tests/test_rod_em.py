"""The energy-momentum step of the rod (time.scheme = "energy-momentum", varint/schemes/em_rod.py, docs/theory.md §12a).

Truths: algebraic identities checked on random data (the discrete gradient's defining property; the step's energy
and momentum balances as identities of its residual), the exact gradient of U by complex step, the midpoint scheme of
docs/theory.md §9 at a much finer step as an independent solver of the same semi-discrete equations (order 2), and the
hard case of §12 where the midpoint rod blows up."""

from pathlib import Path

import numpy as np
import pytest

from helpers import fail_newton_at
from varint.scene.text import to_toml
from varint import Simulation, build_model, parse_scene
from varint.errors import SceneError
from varint.lattice.lie import cay
from varint.terms.rod import unpack_level
from varint.schemes.em_rod import RodEMStep, discrete_gradient, potential, strains


def _scene(n=8, sec=None, curvature=(0.0, 1.0, 2.0), spin=(0.0, 0.0, 2.0), h=5e-3, scheme="midpoint", gravity=None, **extra):
    return build_model(parse_scene(to_toml(_scene_dict(n, sec, curvature, spin, h, scheme, gravity, **extra))))


def _scene_dict(n=8, sec=None, curvature=(0.0, 1.0, 2.0), spin=(0.0, 0.0, 2.0), h=5e-3, scheme="midpoint", gravity=None,
                **extra):
    """The scene of _scene as a dict (to write a scene file)."""
    sec = sec or dict(mass_per_length=1.0, rotary_inertia=0.01, bending_stiffness=1.0, torsional_stiffness=0.8,
                      axial_stiffness=100.0, shear_stiffness=60.0)
    rod = dict(sec, dimension=3, ends={"s0": "free", "sL": "free"})
    rod.update({k: v for k, v in extra.items() if v is not None})
    rod["initial"] = {"curvature": list(curvature), "angular_velocity": list(spin)}
    d = {"title": "em", "tube": {"length": 1.0, "nodes": n + 1, "radius": 0.01}, "rod": rod,
         "time": {"step": h, "end": 1.0, "scheme": scheme}}
    if gravity is not None:
        d["environment"] = {"gravity": list(gravity)}
    return d


def _stepped(constraint, n=5, h=0.01):
    """A RodEMStep on _scene after one step (its factorisation and predictor data made)."""
    s = RodEMStep(_scene(n=n, h=h, constraint=constraint), h)
    s.step()
    return s


# PyElastica's benchmark section (docs/theory.md §12): solid, r = 1 cm, E = 1 MPa, rho = 1000, G = E/1.5, k = 4/3
def _pyelastica(radius=0.01):
    E, G = 1e6, 1e6 / 1.5
    A, I = np.pi * radius ** 2, np.pi * radius ** 4 / 4
    return dict(mass_per_length=1000 * A, rotary_inertia=1000 * I, bending_stiffness=E * I, torsional_stiffness=2 * G * I,
                axial_stiffness=E * A, shear_stiffness=4 / 3 * G * A)


def _random_pair(rng, N, orthonormal):
    r0 = np.cumsum(rng.normal(size=(N + 1, 3)) * 0.3 + [1, 0, 0], 0)
    r1 = r0 + 0.2 * rng.normal(size=r0.shape)
    if orthonormal:
        D0 = cay(rng.normal(size=(N + 1, 3)))
        D1 = D0 @ cay(0.5 * rng.normal(size=(N + 1, 3)))
    else:
        D0 = np.eye(3) + 0.3 * rng.normal(size=(N + 1, 3, 3))
        D1 = D0 + 0.3 * rng.normal(size=D0.shape)
    return r0, D0, r1, D1


@pytest.mark.parametrize("orthonormal", [True, False])
def test_discrete_gradient_property(orthonormal):
    """grad_d U(a, b) . (b - a) = U(b) - U(a) for random a, b; and grad_d U(a, a) = grad U(a) (complex step)."""
    rng = np.random.default_rng(1)
    N, ds = 7, 1.0 / 7
    Jd, Kd = np.array([0.7, 1.0, 1.3]), np.array([90.0, 40.0, 60.0])
    for _ in range(5):
        r0, D0, r1, D1 = _random_pair(rng, N, orthonormal)
        Fr, FD = discrete_gradient(r0, D0, r1, D1, ds, Jd, Kd)
        dU = potential(r1, D1, ds, Jd, Kd) - potential(r0, D0, ds, Jd, Kd)
        work = np.sum(Fr * (r1 - r0)) + np.sum(FD * (D1 - D0))
        scale = np.sum(np.abs(Fr * (r1 - r0))) + np.sum(np.abs(FD * (D1 - D0)))
        assert abs(work - dU) < 1e-14 * scale, (work, dU)
    # consistency: at a = b it is the gradient of U (complex step of U, an independent computation)
    Fr, FD = discrete_gradient(r0, D0, r0, D0, ds, Jd, Kd)
    q = np.concatenate([r0.ravel(), D0.ravel()])
    g = np.empty_like(q)
    for k in range(q.size):
        qc = q.astype(complex)
        qc[k] += 1e-30j
        g[k] = potential(qc[: 3 * (N + 1)].reshape(N + 1, 3), qc[3 * (N + 1):].reshape(N + 1, 3, 3), ds, Jd, Kd).imag / 1e-30
    assert np.max(np.abs(np.concatenate([Fr.ravel(), FD.ravel()]) - g)) < 1e-12 * np.max(np.abs(g))


def test_discrete_gradient_annihilates_rigid_motions():
    """Sum F_r = 0 and sum rbar x F_r + Dbar_i x F_D,i = 0: translation and rotation invariance at the midpoint
    (what conserves P and J)."""
    rng = np.random.default_rng(2)
    N, ds = 7, 1.0 / 7
    Jd, Kd = np.array([0.7, 1.0, 1.3]), np.array([90.0, 40.0, 60.0])
    for orth in (True, False):
        r0, D0, r1, D1 = _random_pair(rng, N, orth)
        Fr, FD = discrete_gradient(r0, D0, r1, D1, ds, Jd, Kd)
        rb, Db = 0.5 * (r0 + r1), 0.5 * (D0 + D1)
        scale = np.max(np.abs(Fr)) * np.max(np.abs(rb)) + np.max(np.abs(FD))
        assert np.max(np.abs(Fr.sum(0))) < 1e-13 * np.max(np.abs(Fr))
        torque = np.cross(rb, Fr).sum(0) + np.cross(np.swapaxes(Db, 1, 2), np.swapaxes(FD, 1, 2)).sum((0, 1))
        assert np.max(np.abs(torque)) < 1e-13 * scale * (N + 1)


@pytest.mark.parametrize("constraint", ["none", "inextensible_unshearable"])
def test_residual_energy_and_momentum_identities(constraint):
    """For ANY unknowns z (not only a solution): H_1 - H_0 = (dq/h).R_q(z) - lambda.(g(q_1) - g(q_0))
    [- ds mu.(Gamma(q_1) - Gamma(q_0)) with rod.constraint], P_1 - P_0 = sum R_r,
    J_1 - J_0 = sum rbar x R_r + Dbar_i x R_D,i, with v_1 = 2 dq/h - v_0.  So a step that solves R = 0 changes E by
    exactly zero (g(q_0) = 0, Gamma(q_0) = chi) and P, J by zero."""
    s = RodEMStep(_scene(h=0.01, constraint=constraint), 0.01)
    rng = np.random.default_rng(3)
    h, N = s.h, s.N
    for _ in range(3):
        r1 = s.r + h * s.v + 0.01 * rng.normal(size=s.r.shape)
        D1 = s.D + h * s.V + 0.01 * rng.normal(size=s.D.shape)
        lam = rng.normal(size=(N + 1, 6))
        mu = rng.normal(size=(N + 1, 3))
        mu[-1] = 0.0
        z = s._pack(r1 - s.r, D1 - s.D, lam, mu)  # the unknowns are the increments
        R = s.residual(z).reshape(N + 1, s.nv)
        Rr, RD = R[:, :3], R[:, 3:12].reshape(N + 1, 3, 3)
        t = RodEMStep(_scene(h=0.01, constraint=constraint), 0.01)
        t.r, t.D, t.v, t.V = r1, D1, 2 * (r1 - s.r) / h - s.v, 2 * (D1 - s.D) / h - s.V
        g0 = np.array([(s.D[:, :, i] * s.D[:, :, j]).sum(1) - (i == j) for i, j in ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))]).T
        dH = t.energy() - s.energy()
        pred = np.sum((r1 - s.r) / h * Rr) + np.sum((D1 - s.D) / h * RD) - np.sum(lam * (R[:, 12:18] - g0))
        if s.constrained:  # the constraint rows are Gamma(q_1) - chi; Gamma(q_0) = chi
            assert np.max(np.abs(strains(s.r, s.D, s.ds)[1] - [1, 0, 0])) < 1e-14
            pred -= s.ds * np.sum(mu[:-1] * R[:-1, 18:])
        assert abs(dH - pred) < 1e-12 * (abs(s.energy()) + np.sum(np.abs((D1 - s.D) / h * RD)))
        assert np.allclose(t.linear_momentum() - s.linear_momentum(), Rr.sum(0), rtol=0, atol=1e-13)
        rb, Db = 0.5 * (s.r + r1), 0.5 * (s.D + D1)
        dJ = np.cross(rb, Rr).sum(0) + np.cross(np.swapaxes(Db, 1, 2), np.swapaxes(RD, 1, 2)).sum((0, 1))
        assert np.allclose(t.angular_momentum() - s.angular_momentum(), dJ, rtol=0, atol=1e-12)
        # the closed forms the rigid polish uses (internal and constraint forces' sums dropped) are the same sums
        P_closed, J_closed, _, _ = s._momentum_residuals(z)
        assert np.allclose(P_closed, Rr.sum(0), rtol=0, atol=1e-12 * np.abs(Rr).sum())
        assert np.allclose(J_closed, dJ, rtol=0, atol=1e-12 * np.abs(Rr).sum())


def test_energy_momenta_at_a_step_where_the_midpoint_blows_up():
    """docs/theory.md §12's hard case made harder: PyElastica's section slender (r = 2 mm, EA L^2/EI = 1e6), free arc
    kappa = 2 spinning at 2 rad/s, N = 50, h = 8 ms: the midpoint rod fails at step 114 (3D; the planar model explodes at step 109, §9a).  The
    energy-momentum step runs with E to 1e-12, P and J to round-off and orthonormal frames."""
    h = 8e-3
    m = _scene(n=50, sec=_pyelastica(0.002), curvature=(0, 0, 2.0), spin=(0, 0, 2.0), h=h)
    s = RodEMStep(m, h)
    H0 = m.rod.level_energy(m.rod.Lam0, m.rod.r0, m.rod.p0, m.rod.Pi0)
    E0, P0, J0 = s.energy(), s.linear_momentum(), s.angular_momentum()
    p_scale = np.sum(s.m * np.linalg.norm(s.v, axis=1))  # round-off reference: the sum of the nodes' |momenta|
    assert abs(E0 - sum(H0.values())) < 1e-14 * E0  # the same energy as the midpoint's monitor at the start
    worst = 0.0
    for _ in range(150):
        s.step()
        worst = max(worst, abs(s.energy() / E0 - 1))
    assert worst < 1e-12
    Js = np.linalg.norm(J0)
    assert np.max(np.abs(s.linear_momentum() - P0)) < 1e-13 * p_scale
    assert np.max(np.abs(s.angular_momentum() - J0)) < 1e-13 * Js
    assert s.orthonormality() < 1e-13


def test_momenta_to_round_off_over_a_thousand_hard_steps():
    """Momenta to round-off, not to the residual's floor (docs/theory.md §12a, "Momenta to round-off"): the base hard
    case of §12 (PyElastica's section, r = 1 cm, free arc kappa = 2 spinning at 2 rad/s, N = 50) at h = 5 ms, where
    the midpoint rod blows up.  With increments as unknowns and the rigid polish, P and J move by 4.7e-15 and 2.6e-15
    of |J0| (/L) over 1000 steps (bound 1e-14); without the polish dP reaches ~5e-14, with positions as unknowns and
    no polish (the first version) 1.8e-13 and 2.0e-13, a random walk that reached 5e-12 over 10^5 steps."""
    h = 5e-3
    s = RodEMStep(_scene(n=50, sec=_pyelastica(), curvature=(0, 0, 2.0), spin=(0, 0, 2.0), h=h), h)
    E0, P0, J0 = s.energy(), s.linear_momentum(), s.angular_momentum()
    Js = np.linalg.norm(J0)
    dP = dJ = dE = 0.0
    for n in range(1000):
        s.step()
        if n % 10 == 9:
            dP = max(dP, np.max(np.abs(s.linear_momentum() - P0)) / Js)  # L = 1 m
            dJ = max(dJ, np.max(np.abs(s.angular_momentum() - J0)) / Js)
            dE = max(dE, abs(s.energy() / E0 - 1))
    assert dP < 1e-14 and dJ < 1e-14, (dP, dJ)
    assert dE < 2e-13


def test_the_inextensible_rod_where_the_constrained_midpoint_fails():
    """docs/theory.md §9a: with rod.constraint the midpoint rod still fails on the hard case spinning at 8 rad/s at
    h = 8 ms (it stops at step 274: a node turns by 140 degrees in one step, E = 3.8 E0; the unresolved torsional
    mode).  The energy-momentum step with the constraint (docs/theory.md §12a, "The inextensible rod") runs 600 steps
    there with Gamma = chi, E, P and J to round-off (measured over 2000 steps: E 6e-15, Gamma - chi 1.2e-14)."""
    h = 8e-3
    m = _scene(n=50, sec=_pyelastica(), curvature=(0, 0, 2.0), spin=(0, 0, 8.0), h=h, constraint="inextensible_unshearable")
    s = RodEMStep(m, h)
    E0, P0, J0 = s.energy(), s.linear_momentum(), s.angular_momentum()
    Js = np.linalg.norm(J0)
    worst = con = 0.0
    for _ in range(600):
        s.step()
        worst = max(worst, abs(s.energy() / E0 - 1))
        con = max(con, float(np.max(np.abs(strains(s.r, s.D, s.ds)[1] - [1, 0, 0]))))
    assert worst < 1e-13 and con < 1e-13, (worst, con)
    assert np.max(np.abs(s.linear_momentum() - P0)) < 1e-14 * Js  # L = 1 m
    assert np.max(np.abs(s.angular_momentum() - J0)) < 1e-14 * Js
    assert s.orthonormality() < 1e-13


@pytest.mark.parametrize("ends", [("pinned", "pinned"), ("clamped", "free")])
def test_the_constrained_step_with_supports_and_gravity(ends):
    """rod.constraint with supports and gravity (a scene file through parse_scene: the pair is accepted): the energy
    with gravity's potential conserved, Gamma = chi held, the frames orthonormal."""
    text = to_toml(_scene_dict(n=10, spin=(0.0, 0.0, 0.0), scheme="energy-momentum", gravity=(0.0, -9.81, 0.0),
                               constraint="inextensible_unshearable", ends={"s0": ends[0], "sL": ends[1]}))
    sim = Simulation(build_model(parse_scene(text)))
    E0 = sim.monitors()["energy"]
    for _ in range(50):
        sim.step()
    mo = sim.monitors()
    assert abs(mo["energy"] - E0) < 1e-13 * (abs(E0) + 9.81)
    assert mo["rod_constraint_residual"] < 1e-13 and mo["frame_orthogonality"] < 1e-13
    assert np.max(np.abs(sim.fields()["rod/r"][0] - sim.model.rod.r0[0])) == 0.0  # the held end stays exactly put


def test_order_two_against_the_midpoint_scheme():
    """Both schemes discretise the same semi-discrete rod (same lumped kinetic energy, same potential): the
    energy-momentum positions at T converge at order 2 to those of the §9 midpoint scheme at T/2560 (8x finer than
    the finest step tried; errors 3.6e-3, 9.3e-4, 2.6e-4, 6.5e-5 at 40, 80, 160, 320 steps; rates 1.95, 1.85, 1.98)."""
    T, N = 0.2, 8
    ref = Simulation(_scene(n=N, h=T / 2560), h=T / 2560)
    for _ in range(2560):
        ref.step()
    _, r_ref, origin = unpack_level(ref.state.q[ref.model.rod_q], N)
    r_ref = r_ref + origin
    errs = []
    for k in (40, 80, 160, 320):
        s = RodEMStep(_scene(n=N, h=T / k), T / k)
        for _ in range(k):
            s.step()
        errs.append(np.max(np.abs(s.r + s.origin - r_ref)))
    rates = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    assert np.all((rates > 1.75) & (rates < 2.3)), (errs, rates)


def test_scene_key_runs_and_refuses():
    """time.scheme = "energy-momentum" through Simulation: the monitors carry the conserved energy and momenta; scenes
    it does not cover are refused in one line naming the key."""
    sim = Simulation(_scene(n=10, h=0.01, scheme="energy-momentum"))
    m0 = sim.monitors()
    for _ in range(30):
        sim.step()
    mo = sim.monitors()
    assert sim.state.n == 30 and abs(sim.state.t - 0.3) < 1e-12
    assert abs(mo["energy"] / m0["energy"] - 1) < 1e-13
    assert np.max(np.abs(mo["angular_momentum"] - m0["angular_momentum"])) < 1e-13 * np.linalg.norm(m0["angular_momentum"])
    for bad in (dict(measure="paper"),):
        with pytest.raises(SceneError, match=r"time\.scheme: 'energy-momentum'"):
            Simulation(_scene(n=4, scheme="energy-momentum", **bad))
    examples = Path(__file__).resolve().parent.parent / "examples"
    for name in ("liquid_pulse_tube_law.toml", "garden_hose.toml"):  # a tube without a rod; a rod with a fluid
        text = (examples / name).read_text().replace("[time]\n", '[time]\nscheme = "energy-momentum"\n')
        with pytest.raises(SceneError, match=r"time\.scheme: 'energy-momentum'"):
            Simulation(build_model(parse_scene(text)))


@pytest.mark.parametrize("constraint", ["none", "inextensible_unshearable"])
def test_compiled_residual_equals_the_reference(constraint):
    """The compiled kernel (iterations and complex-step Jacobian) computes RodEMStep.residual, real and complex."""
    s = RodEMStep(_scene(n=6, h=0.01, constraint=constraint), 0.01)
    s.step()
    rng = np.random.default_rng(4)
    z = s._predict() + 1e-2 * rng.normal(size=(s.N + 1) * s.nv)
    ref = s.residual(z)
    assert np.max(np.abs(s.residual_compiled(z) - ref)) < 1e-14 * np.max(np.abs(ref))
    zc = z[None, :] + 1e-30j * rng.normal(size=(3, z.size))
    out = np.empty_like(zc)
    s._kernel(zc, out)
    refc = s.residual(zc)
    assert np.max(np.abs(out.real - refc.real)) < 1e-14 * np.max(np.abs(ref))
    assert np.max(np.abs(out.imag - refc.imag)) < 1e-12 * np.max(np.abs(refc.imag))


@pytest.mark.parametrize("constraint", ["none", "inextensible_unshearable"])
def test_jacobian_is_the_residual_derivative_in_space_and_body_frames(constraint):
    """The complex-step Jacobian against central differences of the residual; its body-frame form is T^T J T."""
    s = _stepped(constraint)
    rng = np.random.default_rng(8)
    z = s._predict() + 1e-3 * rng.normal(size=(s.N + 1) * s.nv)
    J = s.jacobian(z).toarray()
    eps = 1e-6
    for k in rng.choice(z.size, 12, replace=False):
        e = np.zeros(z.size)
        e[k] = eps
        fd = (s.residual(z + e) - s.residual(z - e)) / (2 * eps)
        assert np.allclose(J[:, k], fd, rtol=0, atol=1e-6 * (1 + np.max(np.abs(fd))))
    T = s._body_frames()
    assert np.allclose(s.jacobian(z, body=True).toarray(), (T.T @ J @ T), rtol=0, atol=1e-12 * np.max(np.abs(J)))


def test_a_stale_factorisation_gives_the_same_step():
    """Chord Newton's answer does not depend on the kept factorisation: a step on the factorisation of 40 steps back
    ends at the same solution as one on a fresh Jacobian, to the round-off floor (the stopping rule iterates to the
    floor whatever the matrix)."""
    a, b = (RodEMStep(_scene(n=12, h=5e-3), 5e-3) for _ in range(2))
    a.step()
    b.step()
    old = a._lu
    for _ in range(40):
        a.step()
        b.step()
    b._lu = None
    a._lu = old
    a.step()
    b.step()
    assert np.max(np.abs(a.r - b.r)) < 1e-13 and np.max(np.abs(a.D - b.D)) < 1e-13


@pytest.mark.parametrize("constraint", ["none", "inextensible_unshearable"])
def test_body_frame_rotation_kernel_is_the_block_diagonal_T(constraint):
    """_k_rotate (Newton's body-frame change of unknowns) against the sparse T of RodEMStep._body_frames."""
    s = _stepped(constraint)
    x = np.random.default_rng(7).normal(size=(s.N + 1) * s.nv)
    T = s._body_frames()
    assert np.allclose(s._rotate(x), T @ x, rtol=0, atol=1e-15)
    assert np.allclose(s._rotate(x, transpose=True), T.T @ x, rtol=0, atol=1e-15)


@pytest.mark.parametrize("torque", [False, True], ids=["", "tip-torque"])
def test_a_resumed_run_continues_the_uninterrupted_one(tmp_path, torque):
    """varint run --resume with the energy-momentum step: the checkpoint carries the step's own state (director
    velocities, multipliers, last increment, floating origin, a tip torque's work; RodEMStep.state_data) and the kept
    factorisation is dropped at every checkpoint, so the run resumed from the step-30 checkpoint repeats the
    uninterrupted one bit for bit."""
    from varint.run.io import read_run
    from varint.run.runner import run_scene

    d = _scene_dict(h=5e-3, scheme="energy-momentum", load={"torque": TORQUE} if torque else None)
    d["time"]["end"] = 0.5
    d["output"] = {"every": 10}
    scene = parse_scene(to_toml(d))
    full, part = tmp_path / "full.h5", tmp_path / "part.h5"
    run_scene(scene, str(full), progress=False)
    run_scene(scene, str(part), progress=False, max_steps=37)  # stops between two records
    run_scene(scene, str(part), resume=True, progress=False)
    a, b = read_run(full), read_run(part)
    assert np.array_equal(a["time"], b["time"]) and len(a["time"]) == 11
    for k in a["fields"]:
        assert np.array_equal(a["fields"][k], b["fields"][k]), k
    for k in a["monitors"]:
        assert np.array_equal(a["monitors"][k], b["monitors"][k]), k
    E = b["monitors"]["energy"]
    if torque:
        assert abs(b["monitors"]["external_work"][-1]) > 1e-4 * abs(E[0])
        E = E - b["monitors"]["external_work"]
    assert np.max(np.abs(E / E[0] - 1)) < 1e-12


def test_supports_gravity_and_tip_force():
    """Clamped, pinned and free ends with gravity and a dead tip force (potentials linear in r, exact discrete
    gradients): the energy with the loads' potential is conserved to round-off; on a free rod P changes by exactly
    h sum(m) g per step and the angular momentum about the g axis is conserved."""
    g = [0.0, -9.81, 0.0]
    for ends, load in ((("clamped", "free"), {"force": [0.0, 0.0, -0.5]}), (("pinned", "pinned"), {}),
                       (("free", "free"), {})):
        m = _scene(n=10, h=0.01, scheme="energy-momentum", spin=(0, 0, 0) if ends[0] != "free" else (0, 0, 2.0),
                   ends={"s0": ends[0], "sL": ends[1]}, load=load or None, gravity=g)
        sim = Simulation(m)
        m0 = sim.monitors()
        scale = abs(m0["energy"]) + float(np.sum(m.rod.node_mass)) * 9.81 * m.rod.L
        for _ in range(60):
            sim.step()
        mo = sim.monitors()
        assert abs(mo["energy"] - m0["energy"]) < 1e-13 * scale, ends
        if ends[0] == "free":
            dP = np.asarray(mo["linear_momentum"]) - m0["linear_momentum"]
            assert np.allclose(dP, 60 * 0.01 * float(np.sum(m.rod.node_mass)) * np.array(g), rtol=1e-12, atol=1e-14)
            Jg = lambda o: float(np.dot(o["angular_momentum"], g))  # noqa: E731
            assert abs(Jg(mo) - Jg(m0)) < 1e-13 * np.linalg.norm(m0["angular_momentum"]) * 9.81
        else:
            _, r, o = unpack_level(sim.state.q[m.rod_q], m.N)
            assert np.max(np.abs(r[0] + o - m.rod.r0[0])) == 0.0 and np.max(np.abs(mo["kinetic_energy"])) > 0


@pytest.mark.parametrize("keep", ["newton-at-h", "half-steps"])
def test_a_step_newton_fails_at_h_is_solved_from_two_half_steps(keep):
    """varint.schemes.em_rod.halved_step for the rod alone (docs/theory.md §12c): the four starts at h fail (induced); Newton at
    h from the level two half steps reach finds the unfailing step's solution, or, failing too, the two half steps
    are the step (a step of h/2 taken twice).  Energy and momenta are conserved either way."""
    h = 5e-3
    model = _scene(n=8, h=h)
    s = RodEMStep(model, h)
    s.step()
    before = s.state_data()
    E0, P0, J0 = s.energy(), s.linear_momentum(), s.angular_momentum()
    seen = fail_newton_at(s, h, calls=4 if keep == "newton-at-h" else None)
    s.step()
    assert s.last["fallback"] == 2 and s.stats["halvings"] == 1 and s.n == 2 and seen.count(h) == 5
    ref = RodEMStep(model, h if keep == "newton-at-h" else h / 2)
    ref.restore(before, 1)
    if keep == "half-steps":
        ref._prev = None
        ref.step()
    ref.step()
    assert np.abs(s.r - ref.r).max() < 1e-12 and np.abs(s.D - ref.D).max() < 1e-11
    assert abs(s.energy() / E0 - 1) < 1e-12
    Js = np.linalg.norm(J0)
    assert np.abs(s.linear_momentum() - P0).max() < 1e-13 * Js and np.abs(s.angular_momentum() - J0).max() < 1e-13 * Js


def test_a_rod_far_from_the_origin_keeps_its_digits_by_the_floating_origin():
    """A free rod's positions are kept relative to an origin moved with node 0 on a binary grid (varint.terms.rod.origin_shift,
    an exact subtraction; docs/theory.md §12c).  The spinning arc, also travelling at 3 m/s and started 2.2 km away,
    steps as the same rod at the origin (its shape to the rounding of the start), its absolute positions follow, and
    energy and angular momentum about the centre of mass keep to round-off after the first step (measured 3e-15 of K0
    and 4e-15 of abs(J_cm); without the floating origin 4.3e-12 and 1.4e-11)."""
    h = 5e-3

    def j_cm(s):  # about the centre of mass, from the positions relative to it (J - rc x P would round at |rc||P|)
        x = s.r - np.sum(s.m[:, None] * s.r, 0) / s.m.sum()
        return (np.cross(x, s.m[:, None] * s.v).sum(0)
                + np.cross(np.swapaxes(s.D, 1, 2), np.swapaxes(s.E[:, None, :] * s.V, 1, 2)).sum((0, 1)))

    far = np.array([1000.0, -2000.0, 500.0])
    runs = {}
    for name, c in (("here", np.zeros(3)), ("far", far)):
        s = RodEMStep(_scene(n=8, h=h), h)
        s.r, s.v = s.r + c, s.v + [3.0, 0.0, 0.0]
        K0 = 0.5 * np.sum(s.m * np.sum(s.v ** 2, 1)) + 0.5 * np.sum(s.E[:, None, :] * s.V ** 2)
        s.step()  # its positions rounded at 2.2 km before it; relative to the floating origin after
        E0, J0 = s.energy(), j_cm(s)
        worst_E = worst_J = 0.0
        for _ in range(60):
            s.step()
            worst_E = max(worst_E, abs(s.energy() - E0) / K0)
            worst_J = max(worst_J, np.abs(j_cm(s) - J0).max() / np.linalg.norm(J0))
        runs[name] = s, worst_E, worst_J
    here, far_run = runs["here"][0], runs["far"][0]
    assert np.abs(far_run.origin - (far + [0.9, 0, 0])).max() < 1.0 and np.abs(far_run.r).max() < 2.0
    assert np.abs((far_run.r - far_run.r[0]) - (here.r - here.r[0])).max() < 1e-12
    assert np.abs((far_run.r + far_run.origin - far) - (here.r + here.origin)).max() < 1e-11
    assert runs["far"][1] < 1e-12 and runs["here"][1] < 1e-12
    assert runs["far"][2] < 1e-13 and runs["here"][2] < 1e-13


TORQUE = [0.03, -0.02, 0.05]


def test_a_dead_tip_torque_turns_j_by_h_t_per_step_and_does_its_work():
    """A dead tip torque T (docs/theory.md §12a, "A dead tip torque"): director forces F_i = w x dbar_i at the tip with
    sum_i dbar_i x F_i = T exactly.  On the free spinning arc (through the scene route) every step changes J by h T
    to round-off (Euler's second law) and P not at all, and E - (the torque's work) is conserved to the solver's
    tolerance; clamped at s = 0 (the clamp's reaction takes up J), E - work is conserved as well."""
    h = 0.01
    for ends, spin in ((("free", "free"), (0.0, 0.0, 2.0)), (("clamped", "free"), (0.0, 0.0, 0.0))):
        m = _scene(n=10, h=h, scheme="energy-momentum", spin=spin, ends={"s0": ends[0], "sL": ends[1]},
                   load={"torque": TORQUE})
        sim = Simulation(m)
        m0 = sim.monitors()
        Js = np.linalg.norm(m0["angular_momentum"]) + 60 * h * np.linalg.norm(TORQUE)
        prev = m0
        for _ in range(60):
            sim.step()
            mo = sim.monitors()
            if ends[0] == "free":
                dJ = np.asarray(mo["angular_momentum"]) - prev["angular_momentum"]
                assert np.abs(dJ - h * np.array(TORQUE)).max() < 1e-14 * Js
                assert np.abs(np.asarray(mo["linear_momentum"]) - m0["linear_momentum"]).max() < 1e-14 * Js
            prev = mo
        assert abs(mo["external_work"]) > 1e-3 * mo["kinetic_energy"]  # the torque does work
        assert abs((mo["energy"] - mo["external_work"]) - m0["energy"]) < 1e-12 * abs(m0["energy"]), ends


def test_a_dead_tip_torque_is_the_midpoint_s_at_order_two():
    """The energy-momentum cantilever (clamped-free, 3D arc) under a dead tip torque converges at order 2 to the §9
    midpoint scheme's solution at T/2560, whose torque enters by Lagrange-d'Alembert (an independent discretisation
    of the same semi-discrete rod and load): errors 4.1e-4, 1.2e-4, 2.9e-5 at 80, 160, 320 steps (rates 1.84, 1.98; 40
    steps are not yet asymptotic, as without the torque), against the torque's own effect on the positions, 0.16."""
    T, N = 0.2, 8
    kw = dict(n=N, spin=(0.0, 0.0, 0.0), ends={"s0": "clamped", "sL": "free"})
    refs = {}
    for name, load in (("torque", {"torque": [0.5, -1.0, 0.8]}), ("none", None)):
        ref = Simulation(_scene(h=T / 2560, load=load, **kw), h=T / 2560)
        for _ in range(2560):
            ref.step()
        _, r_ref, origin = unpack_level(ref.state.q[ref.model.rod_q], N)
        refs[name] = r_ref + origin
    errs = []
    for k in (80, 160, 320):
        s = RodEMStep(_scene(h=T / k, load={"torque": [0.5, -1.0, 0.8]}, **kw), T / k)
        for _ in range(k):
            s.step()
        errs.append(np.max(np.abs(s.r + s.origin - refs["torque"])))
    rates = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    assert np.all((rates > 1.75) & (rates < 2.3)), (errs, rates)
    assert np.max(np.abs(refs["torque"] - refs["none"])) > 100 * errs[0], np.max(np.abs(refs["torque"] - refs["none"]))


def _scalar_newton(R, dR, z0, chord=False):
    """varint.schemes.em_rod.chord_newton on a scalar equation R(z) = 0: (z or the SolverError, residuals, Jacobians)."""
    from types import SimpleNamespace

    from varint.errors import SolverError
    from varint.schemes.em_rod import chord_newton

    step = SimpleNamespace(n=0, tol=1e-13, max_iter=40, rate_refresh=0.5, _lu=None,
                           stats={"residuals": 0, "jacobians": 0})
    slope = {}

    def factor(z):
        step.stats["jacobians"] += 1
        slope["J"] = dR(z[0])
        return SimpleNamespace(solve=lambda r: r / slope["J"])

    try:
        z, _ = chord_newton(step, np.array([z0]), chord, lambda z: np.array([R(z[0])]), factor,
                            lambda r: -step._lu.solve(r), lambda dz: float(abs(dz[0])))
        return z[0], step.stats["residuals"], step.stats["jacobians"]
    except SolverError as exc:
        return exc, step.stats["residuals"], step.stats["jacobians"]


def test_full_newton_gives_up_a_diverging_start_early_and_keeps_its_jacobian_near_the_root():
    """The fallback's full Newton (chord_newton with chord=False): from z0 = 2, Newton on arctan z = 0 diverges
    (|z| grows at every iteration); it is abandoned once the update is DIVERGED times its smallest, after a few
    iterations, not at max_iter (each iteration is a Jacobian: the tumbling rod at 10 ms spent most of its Jacobians on
    such starts, 89 -> 46 ms per step).  Near a root (updates below FULL_NEWTON_TO) it keeps its factorisation."""
    from varint.errors import SolverError

    out, n_res, n_jac = _scalar_newton(np.arctan, lambda z: 1.0 / (1.0 + z * z), 2.0)
    assert isinstance(out, SolverError) and "diverges" in str(out) and n_jac < 10, (out, n_jac)
    z, n_res, n_jac = _scalar_newton(lambda z: z + 0.5 * z * z * z, lambda z: 1.0 + 1.5 * z * z, 0.8)
    assert abs(z) < 1e-14 and n_jac < n_res, (z, n_jac, n_res)  # (without it: a Jacobian per residual)
