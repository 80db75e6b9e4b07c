"""Modes of a tube conveying fluid (varint/analysis/flowing_modes.py, docs/theory.md §13.6) against the classical theory of
pipes conveying fluid: Païdoussis' eq. (3.70) solved independently by varint/exact/pipe_stability.py (Galerkin on beam
modes; validated against the exact determinant in tests/test_pipe_stability.py).  The pipe: L = 1, EI = 1,
M + m = 1 (so u = U sqrt(M), omega = Omega, gamma = g), nearly inextensible and unshearable (EA = kGA = 1e7 EI/L^2),
with a small rotary inertia (radius of gyration 1e-3 L); 40 elements unless said.  Measured errors (40 / 20
elements) are in docs/validation.md; their order is 2.
"""

import json
import subprocess
import sys

import numpy as np
import pytest

from varint.exact import pipe_stability as ps
from varint.errors import VarintError
from varint.analysis.flowing_modes import first_order_modes, flow_matrices, flowing_linearization
from varint.analysis.thresholds import threshold
from varint.model.model import build_model
from varint.analysis.modes import scene_modes, strongest
from varint.scene.standard import pipe_scene_text as pipe_text
from varint.scene.schema import parse_scene


def model_of(*args, **kw):
    return build_model(parse_scene(pipe_text(*args, **kw)))


def u_threshold(ends, beta, lo, hi, nodes=41, gamma=0.0, dim=2, scan=12):
    """(u_c, Omega_c) by the bisection of varint.analysis.thresholds.threshold on fluid.velocity (U = u / sqrt(beta)).

    The bisection only looks inside [lo, hi]; the truth (pipe_stability) is the *first* loss of stability, so the
    pipe is also checked stable at ``scan`` flows from 0.04 u_c up to lo: a false instability window below the
    bracket fails here (it did not before issue 23)."""
    about = "static" if gamma else "initial"
    text = pipe_text(ends, beta, 1.0, nodes, dim, gamma)
    res = threshold(text, lo / np.sqrt(beta), hi / np.sqrt(beta), count=8, about=about, rtol=1e-5)
    uc = res["value"] * np.sqrt(beta)
    for u in np.linspace(0.04 * uc, lo, scan):
        grow = strongest(scene_modes(parse_scene(pipe_text(ends, beta, u, nodes, dim, gamma)), count=8,
                                     about=about)["modes"])["growth_rate"]
        assert grow <= 1e-9, (u / uc, grow)  # a supported pipe: exactly 0; a cantilever: decaying (< 0)
    return uc, res["frequency"]


def test_flow_matrices_integrate_the_catmull_rom_weights_exactly():
    """M int N N^T, int N N'^T, int N N''^T, int N on polynomials the interpolant reproduces (quadratics), and
    the integration by parts C1 + C1^T = [N N^T]_0^L that turns the Lagrangian's gyroscopic term and the two
    momentum fluxes into 2 U C1 (docs/theory.md §13.6)."""
    n, ds = 13, 0.25
    Mf, C1, S, W = (x.toarray() if hasattr(x, "toarray") else x for x in flow_matrices(n, ds, M=2.0))
    s = np.arange(n) * ds
    L = s[-1]
    one = np.ones(n)
    assert W.sum() == pytest.approx(2.0 * L, rel=1e-14)
    assert one @ Mf @ s == pytest.approx(2.0 * L ** 2 / 2, rel=1e-13)
    assert s @ Mf @ s == pytest.approx(2.0 * L ** 3 / 3, rel=1e-13)
    assert one @ C1 @ s ** 2 == pytest.approx(2.0 * L ** 2, rel=1e-13)
    assert np.max(np.abs(S @ s)) < 1e-12  # a straight line has no curvature: no centrifugal load
    assert s @ S @ s ** 2 == pytest.approx(2.0 * 2 * L ** 2 / 2, rel=1e-13)
    ends = np.zeros((n, n))
    ends[-1, -1], ends[0, 0] = 2.0, -2.0
    assert np.max(np.abs(C1 + C1.T - ends)) < 1e-13
    assert np.allclose(Mf, Mf.T, atol=1e-15) and np.all(np.linalg.eigvalsh(Mf) > 0)


def test_straight_flowing_pipe_is_an_equilibrium_without_base_tension():
    """The axial follower force of the jet balances the centrifugal term's axial pull at the straight state."""
    lin = flowing_linearization(model_of(beta=0.5, u=8.0))
    assert lin["unbalanced"] < 1e-13
    assert lin["parameters"]["u"] == pytest.approx(8.0, rel=1e-12)
    assert lin["parameters"]["beta"] == pytest.approx(0.5, rel=1e-12)


@pytest.mark.parametrize("ends, truth", [(("pinned", "pinned"), np.pi), (("clamped", "clamped"), 2 * np.pi)])
def test_supported_pipes_diverge_at_the_classical_velocity(ends, truth):
    """Divergence (a real eigenvalue through 0) at u = pi and 2 pi within 1 % (pipe_stability's too); below it the
    conservative gyroscopic pipe has no growth rate at all (a supported outlet has no transverse follower force)."""
    name = "-".join(ends)
    uc_ref, om_ref, kind = ps.critical_flow_velocity(0.5, name)
    assert kind == "divergence" and uc_ref == pytest.approx(truth, rel=1e-6)
    uc, om = u_threshold(ends, 0.5, 0.9 * truth, 1.1 * truth)
    assert uc == pytest.approx(uc_ref, rel=1e-2)
    assert abs(uc / uc_ref - 1) < 2e-3  # measured 40 elements: 2.6e-4 (pinned), 1.0e-3 (clamped)
    assert om == 0.0
    below = scene_modes(parse_scene(pipe_text(ends, 0.5, 0.98 * uc)), count=10)["modes"]
    assert all(m["growth_rate"] == 0.0 for m in below)
    above = strongest(scene_modes(parse_scene(pipe_text(ends, 0.5, 1.02 * uc)), count=10)["modes"])
    assert above["growth_rate"] > 0.0 and above["frequency"] == 0.0


@pytest.mark.parametrize("beta", [0.1, 0.2, 0.5, 0.8])
def test_cantilever_flutter_threshold_and_frequency(beta):
    """Flutter of the cantilevered pipe (Gregory & Païdoussis 1966): u_cr and the frequency within 2 %."""
    uc_ref, om_ref, kind = ps.critical_flow_velocity(beta, "clamped-free")
    assert kind == "flutter"
    uc, om = u_threshold(("clamped", "free"), beta, 0.9 * uc_ref, 1.1 * uc_ref)
    assert uc == pytest.approx(uc_ref, rel=2e-2)
    assert om == pytest.approx(om_ref, rel=2e-2)  # omega = Omega L^2 sqrt((M+m)/EI) = Omega here


def test_cantilever_flutter_converges_at_second_order():
    uc_ref, om_ref, _ = ps.critical_flow_velocity(0.5, "clamped-free")
    e20 = u_threshold(("clamped", "free"), 0.5, 0.9 * uc_ref, 1.1 * uc_ref, nodes=21)[0] / uc_ref - 1
    e40 = u_threshold(("clamped", "free"), 0.5, 0.9 * uc_ref, 1.1 * uc_ref, nodes=41)[0] / uc_ref - 1
    assert 1.7 < np.log2(abs(e20 / e40)) < 2.5  # measured 1.1e-2 / 2.4e-3: 2.2


@pytest.mark.parametrize("frac, grows", [(0.99, False), (1.01, True)])
def test_growth_rate_changes_sign_at_the_flutter_threshold(frac, grows):
    """Through ``varint modes``' route (scene_modes, strongest as the sweep tabulates): decaying just below the
    threshold (every growth rate negative: the flow damps a cantilever), growing just above, at the flutter
    frequency."""
    uc_ref, om_ref, _ = ps.critical_flow_velocity(0.2, "clamped-free")
    s = strongest(scene_modes(parse_scene(pipe_text(beta=0.2, u=frac * uc_ref)), count=10)["modes"])
    if grows:
        assert s["growth_rate"] > 0.0 and s["frequency"] == pytest.approx(om_ref, rel=2e-2)
    else:
        assert s["growth_rate"] < 0.0


@pytest.mark.parametrize("beta, gamma, published", [
    (0.2, 10.0, None),
    (0.23e-3, 61.1, (6.15, 21.3)),  # Païdoussis (1998) Table 3.4 (Païdoussis 1970), undamped theory
    (2.03e-3, 42.4, (5.62, 19.5)),
])
def test_hanging_cantilever_threshold_with_gravity(beta, gamma, published):
    """Païdoussis' hanging pipes, linearised about the steady state under gravity (the rod's force there is
    T - pA = (M+m) g (L - s)): u_c and the frequency within 2 % of pipe_stability (and of the published values)."""
    uc_ref, om_ref, kind = ps.critical_flow_velocity(beta, "clamped-free", gamma=gamma)
    assert kind == "flutter"
    uc, om = u_threshold(("clamped", "free"), beta, 0.9 * uc_ref, 1.1 * uc_ref, gamma=gamma)
    assert uc == pytest.approx(uc_ref, rel=2e-2)  # measured 40 el.: 2.5e-4, -1.4e-3, -1.2e-3
    assert om == pytest.approx(om_ref, rel=2e-2)
    if published:
        assert (uc, om) == pytest.approx(published, rel=2e-2)
    # gravity changes the threshold: the test can tell the tension from no tension
    assert abs(uc_ref / ps.critical_flow_velocity(beta, "clamped-free")[0] - 1) > 0.1
    lin = flowing_linearization(model_of(beta=beta, u=uc, gamma=gamma), about="static")
    assert lin["unbalanced"] < 1e-9 and lin["parameters"]["gamma"] == pytest.approx(gamma, rel=1e-12)


def test_steady_sag_of_a_horizontal_flowing_cantilever():
    """The steady state under a small transverse gravity (flowing_static, the centrifugal load -U^2 S r of the
    bent tube included) against the linear theory EI w'''' + M U^2 w'' = q, w(0) = w'(0) = 0, w''(L) = w'''(L) = 0:
    w(L) = q/(EI k^2) [L^2/2 - (cos kL + kL sin kL - 1)/k^2], k^2 = M U^2/EI (the flow reduces the sag: at u = 6
    to 12 % of the sag at rest)."""
    from varint.analysis.flowing_modes import flowing_static

    g = 1e-4  # tip deflection ~1e-5 L: linear

    def tip(u, nodes):
        text = pipe_text(beta=0.2, u=u, nodes=nodes).replace("[time]", f"[environment]\ngravity = [0.0, {-g!r}, 0.0]\n[time]")
        (_, r), _ = flowing_static(build_model(parse_scene(text)))
        return r[-1, 1]

    orders = []
    for u in (3.0, 6.0):
        exact = -g / u ** 2 * (0.5 - (np.cos(u) + u * np.sin(u) - 1.0) / u ** 2)
        e20, e40 = (tip(u, n) / exact - 1 for n in (21, 41))
        assert abs(e40) < 3e-3  # measured 5.3e-4, 1.9e-3
        orders.append(np.log2(abs(e20 / e40)))
    assert min(orders) > 1.8


def test_no_flow_agrees_with_the_liquid_filled_tube_at_rest():
    """U = 0: the flowing linearisation's bending frequencies are those of varint.analysis.coupled_modes for the same tube,
    closed and full of liquid at rest (lateral inertia M per length in both: consistent integral here, the labels'
    lumped masses there), to O(ds^2)."""
    from varint.analysis.coupled_modes import coupled_modes

    diffs = []
    for nodes in (21, 41):
        lin = flowing_linearization(model_of(beta=0.5, u=1.0, nodes=nodes), velocity=0.0)
        a = first_order_modes(lin["K"], lin["C"], lin["M"], 3)
        b = coupled_modes(model_of(beta=0.5, nodes=nodes, open_ends=False), 3)
        assert all(m["growth_rate"] == 0.0 for m in a)
        diffs.append(np.array([x["frequency"] / y["frequency"] - 1 for x, y in zip(a, b)]))
    assert np.max(np.abs(diffs[1])) < 1.5e-3  # measured 1.5e-4, 5.0e-4, 8.3e-4
    assert np.all(np.log2(np.abs(diffs[0] / diffs[1])) > 1.7)
    # and the first is Euler-Bernoulli's 1.8751^2 sqrt(EI / ((M+m) L^4))
    assert a[0]["frequency"] == pytest.approx(ps.beam_wavenumbers("clamped-free", 1)[0] ** 2, rel=1e-3)


def test_three_dimensional_pipe_has_the_planar_modes():
    """A 3D rod: each planar mode twice (two bending planes), equal to the planar rod's, below and above the
    flutter threshold (so the same threshold)."""
    for u in (5.0, 6.0):
        lin3 = flowing_linearization(model_of(beta=0.2, u=u, nodes=21, dim=3))
        lin2 = flowing_linearization(model_of(beta=0.2, u=u, nodes=21, dim=2))
        res3 = first_order_modes(lin3["K"], lin3["C"], lin3["M"], 6)
        res2 = first_order_modes(lin2["K"], lin2["C"], lin2["M"], 3)
        for k, m in enumerate(res2):
            for other in res3[2 * k: 2 * k + 2]:
                assert other["frequency"] == pytest.approx(m["frequency"], rel=1e-6)
                assert other["growth_rate"] == pytest.approx(m["growth_rate"], rel=1e-6)
        assert (max(m["growth_rate"] for m in res3) > 0.0) == (u > 5.6)


@pytest.mark.parametrize("extra, fluid, match", [
    ("", ('model = "incompressible"', 'model = "ideal-gas"'), "flowing ideal-gas"),
    ('[wall]\nmodel = "quasistatic"\nthickness = 0.002\ndensity = 1100.0\nyoungs_modulus = 5.0e6\n', None, r"\[wall\]"),
])
def test_refusals_are_one_line(extra, fluid, match):
    text = pipe_text(extra=extra)
    if fluid:
        text = text.replace(*fluid)
    with pytest.raises(VarintError, match=match) as exc:
        scene_modes(parse_scene(text), count=4)
    assert "\n" not in str(exc.value)


def test_cli_modes_of_a_flowing_pipe(tmp_path):
    """``varint modes`` prints the flow's parameters and signed growth rates; ``--json`` has them too."""
    scene = tmp_path / "pipe.toml"
    scene.write_text(pipe_text(beta=0.2, u=6.0, nodes=21))
    out = subprocess.run([sys.executable, "-m", "varint", "modes", str(scene), "-n", "4"], capture_output=True,
                         text=True, check=True).stdout
    assert "u = 6, beta = 0.2" in out and "growth rate" in out
    d = json.loads(subprocess.run([sys.executable, "-m", "varint", "modes", str(scene), "-n", "4", "--json"],
                                  capture_output=True, text=True, check=True).stdout)
    assert d["flow"]["u"] == pytest.approx(6.0) and len(d["modes"]) == 4
    assert max(m["growth_rate"] for m in d["modes"]) > 0.0  # above u_cr = 5.59


def test_sweep_point_on_a_flowing_pipe():
    """The sweep's worker function (varint.sweep.compute_point) on a flowing scene: the largest growth rate."""
    from varint.sweep import compute_point

    below = compute_point(pipe_text(beta=0.2, u=5.4, nodes=21), "modes", count=8)
    above = compute_point(pipe_text(beta=0.2, u=5.8, nodes=21), "modes", count=8)
    assert below["status"] == "ok" and below["growth_rate"] < 0.0 < above["growth_rate"]


@pytest.mark.parametrize("ends, u", [(("clamped", "free"), 6.0), (("pinned", "pinned"), 3.2)])
def test_sparse_eigensolver_matches_the_dense_one(ends, u):
    """The sparse shift-invert path (ARPACK, used above DENSE_FLOWING_LIMIT unknowns) gives the dense path's lowest
    modes: a flutter (growing complex pair) and a divergence (real pair)."""
    lin = flowing_linearization(model_of(ends, beta=0.2, u=u))
    a = first_order_modes(lin["K"], lin["C"], lin["M"], 8, method="sparse")
    b = first_order_modes(lin["K"], lin["C"], lin["M"], 8, method="dense")
    scale = b[-1]["frequency"]
    for x, y in zip(a, b):
        assert abs(x["frequency"] - y["frequency"]) < 1e-7 * scale
        assert abs(x["growth_rate"] - y["growth_rate"]) < 1e-7 * scale
    assert max(m["growth_rate"] for m in a) > 0.0


def test_cli_modes_of_a_hanging_pipe_about_its_steady_state(tmp_path):
    """Gravity along the pipe: about the initial state ``varint modes`` says the state is not in equilibrium;
    ``--about static`` linearises about the steady state (no note) and finds the hanging pipe's flutter above
    pipe_stability's u_c (gamma = 10, beta = 0.2: 6.34) and not below."""
    out = []
    for u, about in ((6.2, "initial"), (6.2, "static"), (6.5, "static")):
        scene = tmp_path / f"hanging_{u}.toml"
        scene.write_text(pipe_text(beta=0.2, u=u, nodes=21, gamma=10.0))
        out.append(json.loads(subprocess.run([sys.executable, "-m", "varint", "modes", str(scene), "-n", "6", "--json",
                                              "--about", about], capture_output=True, text=True, check=True).stdout))
    assert "environment.gravity" in out[0]["note"] and "--about static" in out[0]["note"]
    assert "note" not in out[1] and out[1]["flow"]["gamma"] == pytest.approx(10.0)
    assert max(m["growth_rate"] for m in out[1]["modes"]) < 0.0 < max(m["growth_rate"] for m in out[2]["modes"])
