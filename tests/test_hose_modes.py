"""The garden hose: modes and steady state of the inextensible, unshearable tube conveying fluid
(varint/analysis/flowing_modes.py with rod.constraint = "inextensible_unshearable"; `varint modes` and `varint static`
on examples/garden_hose.toml; docs/theory.md §13.6).

The truth is Païdoussis' hanging cantilever conveying fluid, eq. (3.70), solved independently by
varint.exact.pipe_stability (Galerkin on 40 beam modes; validated against the exact determinant in
tests/test_pipe_stability.py), at the garden hose's own beta = M/(M+m) = 0.618 and gamma = (M+m) g L^3/EI = 17.2
(u_cr = 12.955, omega_cr = 46.30).  The cheap pipe is varint.scene.standard.pipe_scene_text at those (beta, gamma):
L = 1, EI = 1, M + m = 1 (u = U sqrt(M), omega = Omega), rotary inertia m 1e-6, planar, constrained.  Measured
numbers are in docs/validation.md ("The garden hose: the inextensible tube conveying fluid").
"""

from pathlib import Path

import h5py
import numpy as np
import pytest

from varint.analysis.flowing_modes import (first_order_modes, flowing_linearization, flowing_modes, flowing_static,
                                           pipe_parameters)
from varint.analysis.modes import scene_modes, strongest
from varint.analysis.thresholds import threshold
from varint.cli import main
from varint.exact import pipe_stability as ps
from varint.model.model import build_model
from varint.scene.schema import parse_scene
from varint.scene.standard import pipe_scene_text
from varint.terms.rod_constraint import constraint_jacobian

HOSE = Path(__file__).resolve().parent.parent / "examples" / "garden_hose.toml"
HOSE_TEXT = HOSE.read_text()
CONSTRAINED = "inextensible_unshearable"


@pytest.fixture(scope="module")
def hose():
    """The example's model, its pipe parameters and Païdoussis' threshold (u_cr, omega_cr) at its (beta, gamma)."""
    model = build_model(parse_scene(HOSE_TEXT))
    par = pipe_parameters(model)
    uc, om, kind = ps.critical_flow_velocity(par["beta"], "clamped-free", gamma=par["gamma"])
    assert kind == "flutter"
    return {"model": model, "par": par, "uc": uc, "om": om}


def pipe_text(u, hose, nodes=21, constraint=CONSTRAINED, stiffness=None):
    """The dimensionless pipe at the hose's (beta, gamma), hanging; ``stiffness`` replaces EA = kGA = 1e7."""
    text = pipe_scene_text(beta=hose["par"]["beta"], u=float(u), nodes=nodes, gamma=hose["par"]["gamma"],
                           constraint=constraint)
    if stiffness is not None:
        for key in ("axial_stiffness", "shear_stiffness"):
            text = text.replace(f"{key} = 1.0e7", f"{key} = {float(stiffness)!r}")
    return text


def largest_growth(text):
    return strongest(scene_modes(parse_scene(text), count=8, about="static")["modes"])


def test_steady_state_of_the_hanging_hose_carries_T_minus_pA(hose):
    """flowing_static on the hose: straight, Gamma = chi, and the element forces are the effective axial force
    T - pA = (M+m) g (L - s) of the hanging pipe (interior elements to the solver's tolerance; the two elements at
    each end differ by +-M g ds/8, -+M g ds/24, where the Catmull-Rom weights split the liquid's weight); about that
    state the linearisation's force is balanced; about the initial state (no element forces) it is not."""
    model, par = hose["model"], hose["par"]
    rod = model.rod
    (Lam, r), info = flowing_static(model)
    assert np.allclose(r[:, 1:], 0.0, atol=1e-14) and r[-1, 0] == pytest.approx(par["L"], rel=1e-13)
    _, Ga = rod.strains(Lam, r)
    assert np.max(np.abs(Ga - [1.0, 0.0, 0.0])) < 1e-13
    lam = info["element_forces"]
    s_e = (np.arange(rod.N) + 0.5) * rod.ds
    Mgds = par["M"] * par["g"] * rod.ds
    err = (lam[:, 0] - (par["M"] + par["m"]) * par["g"] * (par["L"] - s_e)) / Mgds
    assert np.max(np.abs(err[2:-2])) < 1e-8  # measured 1e-11
    assert err[[0, 1, -2, -1]] == pytest.approx([1 / 8, -1 / 24, 1 / 24, -1 / 8], abs=1e-8)
    assert np.max(np.abs(lam[:, 1:])) < 1e-12
    assert flowing_linearization(model, about="static")["unbalanced"] < 1e-9  # measured 7e-14
    assert flowing_linearization(model)["unbalanced"] > 1e-3


@pytest.mark.parametrize("nodes, frac, measured, truth_rel", [
    (21, 0.95, -0.844, None), (21, 1.05, 4.057, None),
    (41, 0.95, -1.395, 0.15), (41, 1.05, 5.364, 0.1),
])
def test_hanging_pipe_is_stable_below_and_unstable_above_the_classical_threshold(hose, nodes, frac, measured, truth_rel):
    """About the steady state: the largest growth rate is < 0 at 0.95 u_cr and > 0 at 1.05 u_cr (Païdoussis'
    u_cr); at 40 elements it is within 15 % / 10 % of pipe_stability's own growth rate there (-1.541, +5.631)."""
    uc = hose["uc"]
    grow = largest_growth(pipe_text(frac * uc, hose, nodes))["growth_rate"]
    assert grow == pytest.approx(measured, abs=2e-3)
    assert (grow > 0.0) == (frac > 1.0)
    if truth_rel:
        w = np.asarray(ps.eigenvalues(frac * uc, hose["par"]["beta"], "clamped-free", hose["par"]["gamma"]))
        truth = -float(np.min(w[w.real > 1e-9].imag))  # eta ~ exp(i omega tau): growth rate -Im omega
        assert grow == pytest.approx(truth, rel=truth_rel)


def test_threshold_matches_paidoussis_at_two_resolutions(hose):
    """Bisection on fluid.velocity (varint.analysis.thresholds.threshold) about the steady state: u_c and the flutter
    frequency against pipe_stability at 20 and 40 elements, converging at second order (measured u_c +1.62e-2,
    +3.15e-3: order 2.36; omega_c +2.56e-2, +4.76e-3)."""
    uc, om = hose["uc"], hose["om"]
    rt = np.sqrt(hose["par"]["beta"])  # U = u / sqrt(M)
    err = []
    for nodes in (21, 41):
        res = threshold(pipe_text(1.0, hose, nodes), 0.95 * uc / rt, 1.05 * uc / rt, count=8, about="static",
                        rtol=1e-5)
        err.append((res["value"] * rt / uc - 1, res["frequency"] / om - 1))
    (e20, f20), (e40, f40) = err
    assert 0.0 < e20 < 2.5e-2 and 0.0 < e40 < 5e-3  # within 0.5 % at 40 elements
    assert abs(f20) < 4e-2 and abs(f40) < 1e-2
    assert 1.8 < np.log2(e20 / e40) < 2.8


def test_garden_hose_flutters_at_its_flow_speed_above_its_threshold(hose):
    """The example itself (3D, 20 elements, the rubber wall's rotary inertia): every mode twice (two bending planes);
    its threshold on fluid.velocity within 2 % of Païdoussis' U_cr = 8.80 m/s (measured +1.54e-2); at its 10.5 m/s
    (1.19 U_cr) the flutter mode grows (measured 12.88 /s at 70.69 rad/s)."""
    par = hose["par"]
    Uc = hose["uc"] / (par["L"] * np.sqrt(par["M"] / par["EI"]))
    res = threshold(HOSE_TEXT, 0.95 * Uc, 1.05 * Uc, count=8, about="static", rtol=1e-5)
    assert 0.0 < res["value"] / Uc - 1 < 2e-2
    modes = scene_modes(parse_scene(HOSE_TEXT), count=8, about="static")["modes"]
    for a, b in zip(modes[0::2], modes[1::2]):
        assert (a["frequency"], a["growth_rate"]) == pytest.approx((b["frequency"], b["growth_rate"]), rel=1e-8)
    s = strongest(modes)
    assert s["growth_rate"] == pytest.approx(12.88, rel=1e-3) and s["frequency"] == pytest.approx(70.69, rel=1e-3)


def test_constrained_modes_are_the_limit_of_the_stiff_shearable_tube(hose):
    """The shearable tube with EA = kGA = 1e5, 1e6, 1e7 (EI = 1, L = 1) tends to the constrained one at first order in
    1/EA (the penalty): the lowest 6 eigenvalues s differ by 2.8e-3, 2.8e-4, 2.8e-5 of the largest |s| at
    0.95 u_cr (3.6e-3 ... at 1.05 u_cr)."""

    def eig(text):
        lin = flowing_linearization(build_model(parse_scene(text)), about="static")
        return np.array([m["growth_rate"] + 1j * m["frequency"] for m in first_order_modes(lin["K"], lin["C"], lin["M"], 6)])

    for frac in (0.95, 1.05):
        a = eig(pipe_text(frac * hose["uc"], hose))
        d = [np.max(np.abs(eig(pipe_text(frac * hose["uc"], hose, constraint="none", stiffness=E)) - a)) / np.max(np.abs(a))
             for E in (1e5, 1e6, 1e7)]
        assert d[2] < 5e-5
        assert 8.0 < d[0] / d[1] < 12.0 and 8.0 < d[1] / d[2] < 12.0


def test_constrained_modes_keep_the_constraint_and_the_beam_frequency(hose):
    """The modes' displacements (flowing_modes with vectors: q = Z y) satisfy G q = 0; without flow and gravity the
    first frequency is the clamped-free beam's 1.8751^2 sqrt(EI / ((M+m) L^4)) and no mode grows or decays."""
    model = build_model(parse_scene(pipe_text(0.9 * hose["uc"], hose)))
    modes, X = flowing_modes(model, count=6, about="static", vectors=True)
    rod = model.rod
    (Lam, r), _ = flowing_static(model)
    G = constraint_jacobian(Lam, r, rod.ds, rod.ncomp, rod.mask)
    assert X.shape == (rod.nz, 6) and np.max(np.abs(G @ X)) < 1e-12 * np.max(np.abs(X))
    flat = build_model(parse_scene(pipe_scene_text(beta=0.5, u=1.0, constraint=CONSTRAINED)))
    lin = flowing_linearization(flat, velocity=0.0)
    res = first_order_modes(lin["K"], lin["C"], lin["M"], 3)
    assert all(m["growth_rate"] == 0.0 for m in res)
    assert res[0]["frequency"] == pytest.approx(ps.beam_wavenumbers("clamped-free", 1)[0] ** 2, rel=1e-3)


def sagging(u, nodes, g, constraint=CONSTRAINED):
    """The horizontal flowing cantilever (beta = 0.2) under a transverse gravity g: its model."""
    text = pipe_scene_text(beta=0.2, u=u, nodes=nodes, constraint=constraint)
    return build_model(parse_scene(text.replace("[time]", f"[environment]\ngravity = [0.0, {-g!r}, 0.0]\n[time]")))


def test_bent_steady_state_against_the_linear_theory_and_the_stiff_shearable_tube():
    """A bent base state, where the element forces have shear components: the constrained flowing cantilever sagging
    under a small weight against the linear theory EI w'''' + M U^2 w'' = q (as tests/test_flowing_modes.py; measured
    tip errors at 20 / 40 elements -2.3e-3 / -5.3e-4 (u = 3), +8.8e-3 / +1.9e-3 (u = 6): order 2), and under a large
    one (tip 0.77 L below the clamp) against the shearable tube with EA = kGA = 1e7: the shape to 1e-6 L, the first
    mode about it to 1e-5 (measured 1.0e-6 and 9e-7)."""
    g = 1e-4
    for u in (3.0, 6.0):
        exact = -g / u ** 2 * (0.5 - (np.cos(u) + u * np.sin(u) - 1.0) / u ** 2)
        e20, e40 = (flowing_static(sagging(u, n, g))[0][1][-1, 1] / exact - 1 for n in (21, 41))
        assert abs(e40) < 2.5e-3 and np.log2(abs(e20 / e40)) > 1.8
    tips, first = [], []
    for constraint in (CONSTRAINED, "none"):
        lin = flowing_linearization(sagging(3.0, 21, 20.0, constraint), about="static")
        assert lin["unbalanced"] < 1e-12
        tips.append(lin["r"][-1])
        m = first_order_modes(lin["K"], lin["C"], lin["M"], 1)[0]
        first.append(m["growth_rate"] + 1j * m["frequency"])
    assert tips[0][1] == pytest.approx(-0.7714, abs=1e-4)
    assert np.max(np.abs(tips[0] - tips[1])) < 3e-6
    assert abs(first[0] - first[1]) < 1e-5 * abs(first[0])


def test_cli_static_and_modes_of_the_garden_hose(tmp_path, capsys):
    """``varint static`` on the hose writes its steady flowing state as one record (the rod at rest and straight,
    the liquid's pressure hydrostatic from the free jet, the rod's multipliers the wall's tension m g (L - s));
    ``varint modes --about static`` prints the growing flutter mode, ``varint modes`` (about the initial state) says
    the state is not in equilibrium."""
    out = tmp_path / "hose_static.h5"
    assert main(["static", str(HOSE), "-o", str(out)]) == 0
    line = capsys.readouterr().out.strip()
    assert line.startswith(f"wrote {out}: steady flowing state (U = 10.5 m/s)") and "tip at (0.5, 0, 0) m" in line
    model = build_model(parse_scene(HOSE_TEXT))
    par, rod, t = pipe_parameters(model), model.rod, model.tube
    with h5py.File(out, "r") as f:
        assert f.attrs["static"] and f.attrs["records"] == 1
        r = f["fields/rod/r"][0]
        s = f["fields/fluid/s"][0]
        p = f["fields/fluid/pressure"][0]
        slot = f["checkpoint"][f["checkpoint"].attrs["slot"]]
        n = slot["lam"][-rod.nlam:].reshape(rod.N, rod.ncomp)
        assert f["monitors/rod_constraint_residual"][0] < 1e-13
    assert np.allclose(r[:, 1:], 0.0) and r[-1, 0] == pytest.approx(0.5)
    centres = 0.5 * (s[:-1] + s[1:])
    live = np.isfinite(centres)
    rho, g = t.rho0, par["g"]
    assert p[live] == pytest.approx(t.p_ext - rho * g * (par["L"] - centres[live]), rel=1e-6)  # float32 fields
    s_e = (np.arange(rod.N) + 0.5) * rod.ds
    assert n[2:-2, 0] == pytest.approx(par["m"] * g * (par["L"] - s_e[2:-2]), rel=1e-8)
    assert main(["modes", str(HOSE), "--about", "static", "-n", "8"]) == 0
    text = capsys.readouterr().out
    assert "beta = 0.617761, gamma = 17.214" in text and "growth rate 12.9 1/s" in text
    assert main(["modes", str(HOSE), "-n", "2"]) == 0
    assert "environment.gravity" in capsys.readouterr().err


def test_static_of_what_flowing_static_cannot_treat_is_one_line(tmp_path, capsys):
    """An open-ends scene with a gas: ``varint static`` refuses in one line naming the key."""
    scene = tmp_path / "gas_pipe.toml"
    scene.write_text(pipe_scene_text(u=2.0, nodes=11).replace('model = "incompressible"', 'model = "ideal-gas"'))
    assert main(["static", str(scene), "-o", str(tmp_path / "x.h5")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and err.startswith("varint: error: static equilibrium:") and "fluid.model" in err


@pytest.mark.slow
def test_threshold_converges_at_80_elements(hose):
    """The convergence study continued (measured, pipe: u_c +6.92e-4 at 80 elements, order 2.19 from 40; the hose
    itself: +1.54e-2, +2.45e-3, -1.1e-6 at 20/40/80 elements — its wall's rotary inertia, which Païdoussis' Euler-
    Bernoulli pipe leaves out, shifts u_c by -7e-4, measured as the difference from the same hose with 1e-6 of it)."""
    uc = hose["uc"]
    rt = np.sqrt(hose["par"]["beta"])
    err = []
    for nodes in (41, 81):
        res = threshold(pipe_text(1.0, hose, nodes), 0.95 * uc / rt, 1.05 * uc / rt, count=8, about="static", rtol=1e-6)
        err.append(res["value"] * rt / uc - 1)
    assert 0.0 < err[1] < 1e-3 and 1.8 < np.log2(err[0] / err[1]) < 2.6
    par = hose["par"]
    Uc = uc / (par["L"] * np.sqrt(par["M"] / par["EI"]))
    res = threshold(HOSE_TEXT.replace("nodes = 21", "nodes = 81"), 0.95 * Uc, 1.05 * Uc, count=8, about="static",
                    rtol=1e-6)
    assert abs(res["value"] / Uc - 1) < 1e-3
