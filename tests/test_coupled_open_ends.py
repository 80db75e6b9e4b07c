"""Open ends on the coupled tube (docs/theory.md §13.1-13.4): a pipe conveying liquid, stepped in time.

The pipe is Païdoussis' (Fluid-Structure Interactions vol. 1 ch. 3): L = 1, EI = 1, M + m = 1 (so u = U sqrt(M) and
frequencies and rates are dimensionless), an incompressible liquid in a rigid tube, entering through a velocity inlet
at s = 0 (attached to the rod's s = 0 end) and leaving as a free jet.  Thresholds and growth rates are the truths of
varint.exact.pipe_stability (eq. 3.70, an independent Galerkin solver), never varint's own output; the growth rate measured
in a run is also compared with varint.analysis.flowing_modes (a cross-check of the same lattice, not a truth).

Which rod: the cantilever and the steady pipe use rod.constraint = "inextensible_unshearable" (Païdoussis' inextensible
pipe; it removes the stiff axial modes whose parasitic midpoint mode the flow pumps, docs/theory.md §12); a straight
inextensible rod between two pins has an indeterminate tension, so the pinned-pinned pipe is the nearly inextensible
one (EA = 1e7 EI/L^2) on 10 elements, where that axial mode stays quiet (measured; on 20 elements at h = 1e-3 it grows,
docs/validation.md "Open ends on the coupled tube").
"""

import numpy as np
import pytest

from varint.exact import pipe_stability as ps
from varint.analysis.signals import peak_growth_rate
from varint.errors import SceneError
from varint.model.model import build_model
from varint.analysis.modes import scene_modes
from varint.scene.standard import pipe_scene_text
from varint.scene.schema import parse_scene
from varint.run.simulation import Simulation

BETA = 0.2


def pipe(ends=("clamped", "free"), u=1.0, nodes=21, dim=2, h=1e-3, constraint="inextensible_unshearable",
         kick=0.0, profile="tip", gravity=0.0):
    """A [rod] + [fluid] pipe with open ends at Païdoussis' (u, BETA): EI = 1, L = 1, M + m = 1 (varint.scene.standard)."""
    return parse_scene(pipe_scene_text(ends, BETA, u, nodes, dim, gravity, constraint=constraint, h=h, kick=kick,
                                       profile=profile))


def run(scene, T, probe=-1):
    """Step for T seconds; the lateral displacement of node ``probe`` at each level and the last monitors."""
    sim = Simulation(build_model(scene))
    n = int(round(T / sim.h))
    t, y = np.empty(n), np.empty(n)
    for i in range(n):
        sim.step()
        t[i], y[i] = sim.state.t, sim.fields()["rod/r"][probe, 1]
    return sim, t, y


def peak_rate(t, y, skip=1):
    """Growth rate from the peaks of |y| (log-linear fit), leaving out the first ``skip`` (the kick's transient)."""
    return peak_growth_rate(t, y, skip)


def galerkin_rate(ends, u):
    """The largest growth rate of Païdoussis' eq. 3.70 at u (varint.exact.pipe_stability.eigenvalues, Galerkin on 40 beam
    modes: the outside truth; eta ~ exp(i omega tau), tau = t here, so the growth rate is -Im omega)."""
    return float(np.max(-ps.eigenvalues(u, BETA, "-".join(ends)).imag))


def modes_rate(ends, u, nodes):
    """The largest growth rate of varint.analysis.flowing_modes for the same lattice (the nearly inextensible rod: the
    linearisation takes no constrained rod)."""
    d = scene_modes(pipe(ends, u, nodes, constraint="none"), count=6)
    return max(m["growth_rate"] for m in d["modes"])


@pytest.mark.parametrize("dim", [2, 3])
def test_a_straight_pipe_with_steady_flow_stays_straight_and_its_balances_close(dim):
    """Steady flow through an open straight cantilever (below its threshold): the uniform flow is an exact solution of
    the open lattice — parcels injected and removed, the rod at rest — and the energy, momentum and mass balances (the
    fluxes of the entering and leaving parcels, the inlet's work, the clamp's impulse) close to 1e-8 relative."""
    sim, t, y = run(pipe(u=2.0, nodes=11, dim=dim, h=4e-3), 0.5)  # 2.2 flushings of the tube, U = 4.47 m/s
    mon = sim.monitors()
    r = sim.fields()["rod/r"]
    assert np.max(np.abs(r[:, 1:])) < 1e-13
    assert abs(r[-1, 0] - 1.0) < 1e-13
    E0 = 0.5 * BETA * (2.0 / np.sqrt(BETA)) ** 2  # the liquid's kinetic energy 1/2 M L U^2 (the rod is at rest)
    assert abs(mon["energy"] / E0 - 1.0) < 1e-10
    assert abs(mon["energy_balance"]) < 1e-8 * E0
    P0 = BETA * 2.0 / np.sqrt(BETA)
    assert np.max(np.abs(mon["momentum_balance"])) < 1e-8 * P0
    assert abs(mon["mass_balance"]) < 1e-12
    assert np.max(np.abs(mon["support_impulse"])) < 1e-8 * P0  # a straight steady flow pushes the clamp nowhere
    assert mon["parcels"] == 10
    assert mon["rod_constraint_residual"] < 1e-12
    assert mon["constraint_residual"] < 1e-12


@pytest.mark.slow  # 0.4-0.8 min: the slow tier (tests/conftest.py; CI runs it)
def test_pinned_pinned_pipe_is_bounded_below_u_pi_and_diverges_above():
    """Païdoussis' pinned-pinned pipe loses stability by divergence at u = pi (pipe_stability, truth): at 0.9 pi a
    small kick stays bounded (a neutral oscillation), at 1.1 pi it grows exponentially, at the rate of the
    linearisation.  10 elements, the nearly inextensible rod, a kick of 1e-6 m/s (the pins hold the chord, so at a
    deflection of ~sqrt(EI/EA) the stretch's tension saturates the divergence: a linear test needs a small kick)."""
    u_c, _, kind = ps.critical_flow_velocity(BETA, "pinned-pinned")
    assert kind == "divergence" and abs(u_c - np.pi) < 1e-6
    below = pipe(("pinned", "pinned"), 0.9 * u_c, 11, h=3e-3, constraint="none", kick=1e-6, profile="mid")
    _, t, y = run(below, 1.2, probe=5)
    assert np.max(np.abs(y)) < 3e-7  # the kick's own size: v / omega = 1e-6 / 4.2
    assert np.max(np.abs(y[len(y) // 2:])) < 1.1 * np.max(np.abs(y[: len(y) // 2]))
    above = pipe(("pinned", "pinned"), 1.1 * u_c, 11, h=3e-3, constraint="none", kick=1e-6, profile="mid")
    sim, t, y = run(above, 1.2, probe=5)
    assert y[-1] > 30 * np.max(np.abs(y[: len(y) // 4]))
    rate = np.polyfit(t[len(t) // 2:], np.log(y[len(t) // 2:]), 1)[0]
    # outside truth: eq. 3.70's rate at 1.1 pi, 4.389 /s (measured 4.36: -0.7 %); the lattice's own, a cross-check
    assert rate == pytest.approx(galerkin_rate(("pinned", "pinned"), 1.1 * u_c), rel=0.03)
    assert rate == pytest.approx(modes_rate(("pinned", "pinned"), 1.1 * u_c, 11), rel=0.03)
    mon = sim.monitors()
    assert abs(mon["energy_balance"]) < 1e-6 * mon["energy"]
    assert np.max(np.abs(mon["momentum_balance"])) < 1e-9


@pytest.mark.slow  # 0.3-0.4 min: the slow tier (tests/conftest.py; CI runs it)
def test_clamped_clamped_pipe_is_bounded_below_u_2pi_and_diverges_above():
    """The clamped-clamped pipe diverges at u = 2 pi (pipe_stability, truth): bounded at 0.9 u_c, growing at 1.1 u_c at
    the linearisation's rate (measured 8.26 against 8.48 /s, 2.6 %: the rate is fitted while the deflection is between
    1e-6 and 1e-4; beyond ~sqrt(EI/EA) = 3e-4 the clamps' chord tension saturates the divergence, as for the pins)."""
    u_c, _, kind = ps.critical_flow_velocity(BETA, "clamped-clamped")
    assert kind == "divergence" and abs(u_c - 2 * np.pi) < 1e-6
    below = pipe(("clamped", "clamped"), 0.9 * u_c, 11, h=3e-3, constraint="none", kick=1e-6, profile="mid")
    _, t, y = run(below, 1.2, probe=5)
    assert np.max(np.abs(y)) < 2e-7
    assert np.max(np.abs(y[len(y) // 2:])) < 1.1 * np.max(np.abs(y[: len(y) // 2]))
    above = pipe(("clamped", "clamped"), 1.1 * u_c, 11, h=3e-3, constraint="none", kick=1e-6, profile="mid")
    sim, t, y = run(above, 1.2, probe=5)
    a = np.abs(y)
    assert a[-1] > 300 * np.max(a[: len(a) // 4])
    linear = (a > 1e-6) & (a < 1e-4) & (t > 0.3)
    rate = np.polyfit(t[linear], np.log(a[linear]), 1)[0]
    # outside truth: eq. 3.70's rate at 1.1 * 2 pi, 9.23 /s; measured 8.26 (-10.5 %): on 10 elements the lattice's
    # divergence is 1.7 % late (docs/validation.md, order 2), so at 1.1 u_c it is 8 % beyond its own threshold, not 10 %
    assert rate == pytest.approx(galerkin_rate(("clamped", "clamped"), 1.1 * u_c), rel=0.13)
    assert rate == pytest.approx(modes_rate(("clamped", "clamped"), 1.1 * u_c, 11), rel=0.05)
    mon = sim.monitors()
    assert abs(mon["energy_balance"]) < 1e-6 * mon["energy"]
    assert np.max(np.abs(mon["momentum_balance"])) < 1e-9


@pytest.mark.parametrize("frac", [0.93, 1.07])
@pytest.mark.slow  # 0.5-1.7 min: the slow tier (tests/conftest.py; CI runs it)
def test_cantilever_decays_below_its_flutter_threshold_and_grows_above(frac):
    """The cantilevered pipe (beta = 0.2) flutters above u_cr = 5.591 (pipe_stability, truth): a kicked run at
    0.93 u_cr decays, at 1.07 u_cr it grows, with the rate of flowing_modes within 6 % (measured: 0.781 against 0.799 /s,
    -0.936 against -0.928 /s); the constraints hold to round-off and the balances close."""
    u_c, w_c, kind = ps.critical_flow_velocity(BETA, "clamped-free")
    assert kind == "flutter" and abs(u_c - 5.5914) < 1e-3
    sim, t, y = run(pipe(("clamped", "free"), frac * u_c, 21, h=1.8e-3, kick=1e-3), 1.45)
    rate = peak_rate(t, y)
    assert (rate > 0) == (frac > 1)
    # outside truth: eq. 3.70's rates -0.894 / +0.846 /s (measured -0.94 / +0.86)
    assert rate == pytest.approx(galerkin_rate(("clamped", "free"), frac * u_c), rel=0.1)
    assert rate == pytest.approx(modes_rate(("clamped", "free"), frac * u_c, 21), rel=0.1)
    mon = sim.monitors()
    assert mon["rod_constraint_residual"] < 1e-12
    # the levels' volumes, held there (theory §10.12; measured 6.0e-15 / 1.1e-14, 4.9e-11 with the midpoint constraint)
    assert mon["constraint_residual"] < 1e-12
    assert abs(mon["energy_balance"]) < 1e-8 * mon["energy"]  # measured 1.0e-10 / 7.4e-10 (1.9e-8 / 7.9e-8 midpoint)
    assert np.max(np.abs(mon["momentum_balance"])) < 1e-10
    assert abs(mon["mass_balance"]) < 1e-12


@pytest.mark.slow  # 0.5-1.7 min: the slow tier (tests/conftest.py; CI runs it)
def test_the_fast_heavy_flow_of_beta_08_needs_two_parcels_per_element_and_then_grows_at_the_modes_rate():
    """beta = 0.8 at 1.07 u_cr (U = 16 m/s): with one parcel per element the liquid's nodal inertia pulses as the labels
    pass the nodes and a lateral lattice mode grows at ~100 /s (theory §12; Newton fails at t = 0.197 s); with two the
    run grows at flowing_modes' rate (measured +2.313 against +2.249 /s over 8 periods, +2.24 over the last 2.6 of 5)
    and the balances stay closed.
    Outside truth: u_cr = 13.4932 (pipe_stability)."""
    global BETA
    old, BETA = BETA, 0.8
    try:
        u_c, w_c, kind = ps.critical_flow_velocity(BETA, "clamped-free")
        assert kind == "flutter" and abs(u_c - 13.4932) < 1e-3
        scene = pipe(("clamped", "free"), 1.07 * u_c, 21, h=0.62e-3, kick=1e-3)
        scene.fluid["parcels"] = 40
        period = 2 * np.pi / w_c
        sim, t, y = run(scene, 5 * period)
        late = t >= 2.4 * period  # after the kick's beating of several modes (measured: +2.24 /s from there)
        rate = peak_rate(t[late], y[late], skip=0)
        # outside truth: eq. 3.70's +2.78 /s (measured +2.24 to +2.31, -17 to -19 %: on 20 elements the lattice's flutter
        # threshold at beta = 0.8 is 2.5 % late, so the run is at 1.044 of its own threshold)
        assert rate == pytest.approx(galerkin_rate(("clamped", "free"), 1.07 * u_c), rel=0.25)
        assert rate == pytest.approx(modes_rate(("clamped", "free"), 1.07 * u_c, 21), rel=0.1)
        mon = sim.monitors()
        assert abs(mon["energy_balance"]) < 1e-7 * mon["energy"]
        assert np.max(np.abs(mon["momentum_balance"])) < 1e-9
    finally:
        BETA = old


def test_what_open_ends_on_a_rod_cannot_run_is_refused_in_one_line():
    """A pressure inlet or a pressurised outlet on the coupled tube: one line each, before the first step."""
    scene = pipe(constraint="none")
    scene.fluid.ends["outflow_pressure"] = 2.0e5
    with pytest.raises(SceneError, match="outflow_pressure") as e:
        Simulation(build_model(scene))
    assert "\n" not in str(e.value)
    scene = pipe(constraint="none")
    scene.fluid.ends["inflow"] = "pressure"
    with pytest.raises(SceneError, match="fluid.ends") as e:
        Simulation(build_model(scene))
    assert "\n" not in str(e.value)
    # an absorbing outlet and a non-uniform start (the straight tube has them, issue 23) are not on a rod yet
    text = pipe_scene_text(("clamped", "free"), BETA, 1.0, 21, 2, 0.0, constraint="none")
    wk = text.replace('sL = "outflow"', 'sL = "outflow", outflow = "windkessel", windkessel_R1 = 1.0, windkessel_C = 1.0, '
                      'windkessel_R2 = 1.0')
    start = text + '\n[[fluid.initial]]\nfrom = 0.0\nto = 0.5\nvelocity = 1.0\n'
    for t, match in ((wk, "fluid.ends.outflow"), (start, "fluid.initial")):
        assert t != text
        with pytest.raises(SceneError, match=match) as e:
            Simulation(build_model(parse_scene(t)))
        assert "\n" not in str(e.value)


def test_the_inextensible_rod_is_accepted_with_open_ends_only():
    """rod_checks: an incompressible liquid in a rigid inextensible tube is refused when the tube is closed (its volume
    fixes the length), accepted with open ends (the liquid passes through)."""
    pipe()  # parses
    text = """title = "a closed inextensible tube of liquid"
[tube]
length = 1.0
nodes = 11
radius = 0.01
[rod]
mass_per_length = 0.8
rotary_inertia = 1e-6
bending_stiffness = 1.0
torsional_stiffness = 1.0
constraint = "inextensible_unshearable"
ends = { s0 = "clamped", sL = "free" }
[fluid]
model = "incompressible"
density = 600.0
parcels = 10
[time]
step = 1e-3
end = 1e-3
"""
    with pytest.raises(SceneError, match="rod.constraint"):
        parse_scene(text)


def test_a_resumed_run_repeats_the_uninterrupted_one_bit_for_bit(tmp_path):
    """The checkpoint holds the coupled open tube's lattice, its balances' sums (15 entries) and the last level (the
    step energy's): a run stopped mid-way and resumed writes the same records, fields and monitors, bit for bit."""
    from varint.run.io import read_run
    from varint.run.runner import run_scene

    sc = pipe(("clamped", "free"), 3.0, 11, h=4e-3, kick=1e-2, gravity=10.0)
    sc.time["end"] = 0.2
    sc.output["every"] = 5
    run_scene(sc, str(tmp_path / "full.h5"), progress=False)
    run_scene(sc, str(tmp_path / "part.h5"), progress=False, max_steps=23)
    run_scene(sc, str(tmp_path / "part.h5"), progress=False, resume=True)
    a, b = read_run(tmp_path / "full.h5"), read_run(tmp_path / "part.h5")
    assert len(a["time"]) == 11 and set(a["fields"]) == set(b["fields"])
    for k in a["fields"]:
        assert np.array_equal(a["fields"][k], b["fields"][k], equal_nan=True), k
    for k in a["monitors"]:
        assert np.array_equal(a["monitors"][k], b["monitors"][k], equal_nan=True), k
    assert np.max(np.abs(a["fields"]["rod/r"][-1, :, 1])) > 1e-4  # the hose moved
