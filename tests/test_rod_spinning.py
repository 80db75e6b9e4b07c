"""Modes of a rod in steady rotation: the gyroscopic matrix, against the theory of spinning shafts."""

import json
import math

import numpy as np
import pytest

from varint import build_model
from varint.analysis import gyroscopic_modes_of, spinning_shaft_whirl
from varint.errors import SolverError
from varint.lie import cay, dcay
from varint.rod import RodSimulation, _retract, rod_modes, rotating_frame_kinetics

from helpers import to_toml
from test_rod import SECTION, rod_scene

# a thick shaft (radius of gyration 5.8 cm on 1 m) so that the gyroscopic splitting is large; axial and
# torsional modes placed above the first three bending pairs
SHAFT = {"mass_per_length": 0.3, "rotary_inertia": 1e-3, "bending_stiffness": 2.0, "torsional_stiffness": 15.0,
         "axial_stiffness": 1e5, "shear_stiffness": 8e3}
SPIN_RATE = 60.0  # rad/s about the shaft's axis: 2.3 x its first bending frequency


def shaft_model(nodes, spin=SPIN_RATE, h=1e-3):
    return build_model(rod_scene(nodes=nodes, section=SHAFT, ends=("pinned", "pinned"), h=h,
                                 initial={"angular_velocity": [spin, 0.0, 0.0]}))


def whirl(n, spin=SPIN_RATE):
    """Forward and backward whirl of bending mode n from the continuum theory (seen from the ground)."""
    s = SHAFT
    return spinning_shaft_whirl(n * math.pi, s["mass_per_length"], s["rotary_inertia"], 2 * s["rotary_inertia"],
                                s["bending_stiffness"], s["shear_stiffness"], spin)


def test_gyroscopic_modes_of_known_systems():
    """A particle on an isotropic spring seen from a frame turning at W: frequencies |sqrt(k) -+ W|."""
    k, W = 9.0, 1.0
    K = (k - W * W) * np.eye(2)
    G = 2 * W * np.array([[0.0, -1.0], [1.0, 0.0]])
    f = [m["frequency"] for m in gyroscopic_modes_of(K, G, np.ones(2), 2)]
    assert f == pytest.approx([math.sqrt(k) - W, math.sqrt(k) + W], rel=1e-12)
    # without a spring and beyond it: gyroscopic stabilisation keeps both frequencies real...
    f = gyroscopic_modes_of(-W * W * np.eye(2), G, np.ones(2), 2)
    assert [m["growth_rate"] for m in f] == [0.0, 0.0]
    # ...a plain negative stiffness is a growing real pair, listed first
    res = gyroscopic_modes_of(np.diag([-4.0, 1.0]), np.zeros((2, 2)), np.ones(2), 2)
    assert res[0] == {"frequency": 0.0, "growth_rate": pytest.approx(2.0)} and res[1]["frequency"] == pytest.approx(1.0)
    # flutter: unequal stiffnesses under a weak gyroscopic coupling with a negative one (a quadruple +-a +-iw)
    res = gyroscopic_modes_of(np.diag([-1.0, -2.0]), 0.5 * np.array([[0.0, -1.0], [1.0, 0.0]]), np.ones(2), 2)
    lam = np.linalg.eigvals(np.block([[np.zeros((2, 2)), np.eye(2)], [-np.diag([-1.0, -2.0]), -0.5 * np.array([[0.0, -1.0], [1.0, 0.0]])]]))
    assert sorted(m["growth_rate"] for m in res) == pytest.approx(sorted(abs(lam.real))[::2], rel=1e-10)


def test_rotating_frame_kinetics_blocks_match_finite_differences():
    """b, C, H are the first and second derivatives of the exact kinetic energy in the spinning frame."""
    rng = np.random.default_rng(3)
    model = build_model(rod_scene(nodes=5, initial={"curvature": [0.3, -0.5, 0.8]}))
    Omega = np.array([1.3, -0.7, 2.1])
    Lam, r = model.Lam0, model.r0
    b, C, H = rotating_frame_kinetics(model, Omega, Lam, r)
    m = model.section.rhoA * model.w
    rc = (m[:, None] * r).sum(0) / m.sum()
    j = 2
    inertia = model.section.inertia * model.w[j]

    def T(x):  # x = (dr, sigma, dr', sigma') of node j
        dr, sig, drd, sigd = x[:3], x[3:6], x[6:9], x[9:]
        v = np.cross(Omega, r[j] - rc + dr) + drd
        w = cay(sig).T @ Lam[j].T @ Omega + dcay(-sig) @ sigd
        return 0.5 * m[j] * v @ v + 0.5 * w @ (inertia * w)

    x0 = np.zeros(12)
    x0[6:] = 0.0
    eps = 1e-4
    E = np.eye(12) * eps
    grad = np.array([(T(x0 + e) - T(x0 - e)) / (2 * eps) for e in E])
    hess = np.array([[(T(x0 + a + c) - T(x0 + a - c) - T(x0 - a + c) + T(x0 - a - c)) / (4 * eps * eps) for c in E] for a in E])
    scale = np.max(np.abs(hess))
    assert np.max(np.abs(grad[:6] - b[j])) < 1e-8 * np.max(np.abs(grad))
    assert np.max(np.abs(hess[6:, :6] - C[j])) < 1e-6 * scale
    assert np.max(np.abs(hess[:6, :6] - H[j])) < 1e-6 * scale
    assert np.max(np.abs(hess[6:, 6:] - np.diag(np.r_[m[j] * np.ones(3), inertia]))) < 1e-6 * scale
    del rng


def _rotating_frame_prediction(count=3):
    """Seen from the frame spinning at W: forward whirl at |w_f - W|, backward at w_b + W."""
    out = []
    for n in range(1, count + 1):
        wf, wb = whirl(n)
        out += [abs(wf - SPIN_RATE), wb + SPIN_RATE]
    return np.sort(out)


def _nearest(values, targets):
    values = np.asarray(values)
    return np.array([values[np.argmin(np.abs(values - t))] for t in targets])


def test_spinning_shaft_whirl_against_timoshenko_theory_order_two():
    """Pinned-pinned shaft at 2.3x its first critical speed: the three lowest forward/backward whirl pairs."""
    pred = _rotating_frame_prediction()
    errs = []
    for nodes in (21, 41, 81):
        f = [m["frequency"] for m in rod_modes(shaft_model(nodes), count=12)]
        errs.append(np.abs(_nearest(f, pred) / pred - 1))
    errs = np.array(errs)
    assert np.max(errs[-1]) < 1e-3, errs[-1]
    order = np.log2(errs[1] / errs[2])
    big = errs[1] > 1e-5  # order measurable where the error is not at the level of the eigen-solver
    assert np.all(np.abs(order[big] - 2.0) < 0.15), order
    # the test can fail: without the gyroscopic matrix the spin would leave every frequency at its
    # non-spinning value, 9-27 % away from the prediction
    still = np.array([m["frequency"] for m in rod_modes(shaft_model(41, spin=0.0), count=12)])
    bending = [(whirl(n, 0.0)[0]) for n in (1, 2, 3)]
    assert np.min(np.abs(np.subtract.outer(pred, bending)) / pred[:, None]) > 0.05
    assert _nearest(still, bending) == pytest.approx(bending, rel=2e-3)


def time_domain_whirl(nodes=21, h=1e-3, duration=3.0, amp=1e-4):
    """Release the spinning shaft from a small planar bend in its first mode shape and fit the
    midpoint's complex deflection u = y + i z to a e^{i w1 t} + b e^{-i w2 t}: returns (w1, w2)."""
    from scipy.optimize import least_squares

    model = shaft_model(nodes, h=h)
    s = model.r0[:, 0]
    z = np.zeros((model.N + 1, 6))
    z[:, 1] = amp * np.sin(math.pi * s)  # y-deflection in the first mode shape ...
    z[:, 5] = amp * math.pi * np.cos(math.pi * s)  # ... with the sections turned with it
    model.Lam0, model.r0 = _retract(model.Lam0, model.r0, z[model.mask], model.mask)
    sim = RodSimulation(model)
    mid = model.N // 2
    ts, us = [], []
    for _ in range(int(round(duration / h))):
        sim.step()
        r = sim.fields()["rod/r"][mid]
        ts.append(sim.state.t)
        us.append(r[1] + 1j * r[2])
    t, u = np.array(ts), np.array(us)

    def misfit(p):
        w1, w2 = p[:2]
        a, b = p[2] + 1j * p[3], p[4] + 1j * p[5]
        d = a * np.exp(1j * w1 * t) + b * np.exp(-1j * w2 * t) - u
        return np.concatenate([d.real, d.imag]) / amp

    # first guesses from the data alone: the peaks of the (zero-padded) spectrum at positive
    # (forward, in the sense of the spin) and negative (backward) frequency, then a least-squares fit
    spec = np.abs(np.fft.fft(u * np.hanning(len(u)), 16 * len(u)))
    freq = 2 * math.pi * np.fft.fftfreq(16 * len(u), h)
    g1 = freq[np.argmax(np.where(freq > 0, spec, 0))]
    g2 = -freq[np.argmax(np.where(freq < 0, spec, 0))]
    fit = least_squares(misfit, [g1, g2, amp / 2, 0, amp / 2, 0], x_scale=[10, 10, amp, amp, amp, amp])
    return fit.x[0], fit.x[1]


def test_spinning_shaft_time_domain_whirls_at_the_predicted_frequencies():
    """Released from a small planar bend, the spinning shaft's midpoint traces a forward and a backward
    whirl: the time-domain integrator and the continuum theory agree on both frequencies (3 s, ~11
    periods of the backward whirl; the modes of the same 20-element lattice are within 1.2e-3)."""
    w1, w2 = time_domain_whirl()
    wf, wb = whirl(1)
    assert w1 == pytest.approx(wf, rel=2e-3) and w2 == pytest.approx(wb, rel=2e-3), (w1, w2, wf, wb)
    assert abs(wf - wb) > 0.1 * whirl(1, 0.0)[0]  # a real splitting, resolved


def test_modes_cli_reports_the_spinning_frame(tmp_path, capsys):
    from varint.cli import main

    d = {"title": "shaft", "tube": {"length": 1.0, "nodes": 41, "radius": 0.01},
         "rod": dict(SHAFT, ends={"s0": "pinned", "sL": "pinned"}, initial={"angular_velocity": [SPIN_RATE, 0.0, 0.0]}),
         "time": {"step": 1e-3, "end": 1.0}}
    f = tmp_path / "shaft.toml"
    f.write_text(to_toml(d))
    assert main(["modes", str(f), "--json", "-n", "3"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["frame"]["angular_velocity"] == [SPIN_RATE, 0.0, 0.0]
    assert [m["frequency"] for m in out["modes"]][1:] == pytest.approx(_rotating_frame_prediction()[:2], rel=3e-3)


@pytest.mark.parametrize("rod, words", [
    # end over end about a transverse axis: the centrifugal pull is not balanced by the unstretched rod
    (dict(SECTION, ends={"s0": "free", "sL": "free"}, initial={"angular_velocity": [0.0, 0.0, 3.0]}), "steady rotation"),
    (dict(SECTION, ends={"s0": "clamped", "sL": "free"}, initial={"angular_velocity": [3.0, 0.0, 0.0]}), "rod.ends.s0"),
    (dict(SECTION, ends={"s0": "pinned", "sL": "free"}, initial={"velocity": [0.0, 1.0, 0.0]}), "rod.initial.velocity"),
])
def test_modes_of_a_rod_not_in_steady_motion_are_refused(tmp_path, capsys, rod, words):
    from varint.cli import main

    d = {"title": "spin", "tube": {"length": 1.0, "nodes": 11, "radius": 0.01}, "rod": rod, "time": {"step": 1e-3, "end": 1.0}}
    f = tmp_path / "spin.toml"
    f.write_text(to_toml(d))
    assert main(["modes", str(f)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0], err


def test_free_rod_spinning_about_its_axis_is_steady():
    """A free straight rod spinning about its own axis is a relative equilibrium: modes exist, none grows."""
    model = build_model(rod_scene(nodes=11, section=SHAFT, initial={"angular_velocity": [40.0, 0.0, 0.0]}))
    res = rod_modes(model, count=30)
    assert all(m["growth_rate"] < 1e-6 * max(x["frequency"] for x in res) for m in res)
    with pytest.raises(SolverError, match="steady rotation"):
        rod_modes(build_model(rod_scene(nodes=11, section=SHAFT, initial={"angular_velocity": [0.0, 40.0, 0.0]})))
