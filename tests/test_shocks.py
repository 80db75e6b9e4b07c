"""Shock analysis (varint/exact/shocks.py, docs/theory.md §11): each against an outside truth.

* the exact Riemann solver against Toro's Table 4.3 (E. F. Toro, Riemann Solvers and Numerical Methods
  for Fluid Dynamics, tests 1-5 of Table 4.1) and, independently, against the classical jump
  conditions across its shocks, the isentropic relations across its rarefactions and the integral
  conservation laws of its sampled solution;
* the paper's generalised Rankine–Hugoniot conditions against the classical ones (straight tube at rest);
* the traveling shock against the classical M(z) in the rigid-wall limit and the paper's rubber-tube
  example (c ≈ 447 m/s, p_+ ≈ 1.826 atm with beta1 = 1.14e5, beta2 = 8.37e5, a = 0.4782);
* the measurement of jumps in a run file against a synthetic file holding the exact Sod solution.
"""

import json
import math

import h5py
import numpy as np
import pytest

from varint.analysis.shock_measure import measure_shock
from varint.exact import shocks as S
from varint.cli import main

GAMMA = 1.4

# Toro, Table 4.1 (data) and Table 4.3 (exact p*, u*, rho*_L, rho*_R as printed), gamma = 1.4
TORO = [
    ((1.0, 0.0, 1.0), (0.125, 0.0, 0.1), ("0.30313", "0.92745", "0.42632", "0.26557")),
    ((1.0, -2.0, 0.4), (1.0, 2.0, 0.4), ("0.00189", "0.00000", "0.02185", "0.02185")),
    ((1.0, 0.0, 1000.0), (1.0, 0.0, 0.01), ("460.894", "19.5975", "0.57506", "5.99924")),
    ((1.0, 0.0, 0.01), (1.0, 0.0, 100.0), ("46.0950", "-6.19633", "5.99242", "0.57511")),
    ((5.99924, 19.5975, 460.894), (5.99242, -6.19633, 46.0950), ("1691.64", "8.68975", "14.2823", "31.0426")),
]


def _digits(x, ref):
    """x rounds to the printed value ``ref``: within half a unit of its last printed decimal."""
    decimals = len(ref.split(".")[1])
    return abs(x - float(ref)) <= 0.5 * 10 ** (-decimals)


@pytest.mark.parametrize("left,right,ref", TORO, ids=[f"toro{i + 1}" for i in range(5)])
def test_riemann_star_state_matches_toro_table(left, right, ref):
    if left[0] == 5.99924:
        # Test 5 collides the two shocks of tests 3 and 4: Table 4.3's values are those of the exact
        # star states (with the rounded data of Table 4.1, u* is 8.68977)
        t3, t4 = S.RiemannSolution(*TORO[2][:2], GAMMA), S.RiemannSolution(*TORO[3][:2], GAMMA)
        left = (t3.rho_star_right, t3.u_star, t3.p_star)
        right = (t4.rho_star_left, t4.u_star, t4.p_star)
    sol = S.RiemannSolution(left, right, GAMMA)
    got = (sol.p_star, sol.u_star, sol.rho_star_left, sol.rho_star_right)
    for g, r in zip(got, ref):
        assert _digits(g, r), (got, ref)


CASES = TORO + [
    ((1.0, 0.0, 100.0), (1.0, 0.0, 1.0), None),          # pressure ratio 100
    ((1.0, 0.0, 1e5), (0.125, 0.0, 1.0), None),          # pressure ratio 1e5, density ratio 8
]


@pytest.mark.parametrize("left,right,ref", CASES, ids=[f"case{i}" for i in range(len(CASES))])
def test_riemann_waves_satisfy_jump_and_isentropic_relations(left, right, ref):
    """Independent of any table: every shock satisfies RH_*_0 with its speed, every rarefaction keeps
    p/rho^gamma and the Riemann invariant, and the star pressure and velocity agree on both sides."""
    g = GAMMA
    sol = S.RiemannSolution(left, right, g)
    SL, SR = sol.shock_speeds()
    for side, data, rho_s, speed, sign in (("left", left, sol.rho_star_left, SL, -1), ("right", right, sol.rho_star_right, SR, 1)):
        rho, u, p = data
        kind = sol.left_wave if side == "left" else sol.right_wave
        a = S.ideal_gas_state(rho, u, p, g)
        b = S.ideal_gas_state(rho_s, sol.u_star, sol.p_star, g)
        if kind == "shock":
            res = S.rh_classical(a, b, speed)
            scale = {"mass": abs(rho * (u - speed)) + 1e-300, "momentum": p + rho * u * u + rho_s * sol.u_star ** 2,
                     "energy": abs(speed) * (p / (g - 1) + 0.5 * rho * u * u) + abs(u) * p + abs(sol.u_star) * sol.p_star}
            for k in res:
                assert abs(res[k]) <= 1e-12 * max(scale[k], sol.p_star * abs(speed)), (k, res[k])
        else:
            assert abs(sol.p_star / rho_s ** g - p / rho ** g) <= 1e-12 * p / rho ** g
            c, cs = math.sqrt(g * p / rho), math.sqrt(g * sol.p_star / rho_s)
            # J+ = u + 2c/(g-1) across a left rarefaction, J- = u - 2c/(g-1) across a right one
            assert abs((u - sign * 2 * c / (g - 1)) - (sol.u_star - sign * 2 * cs / (g - 1))) <= 1e-12 * (abs(u) + c + cs)


@pytest.mark.parametrize("left,right,ref", CASES, ids=[f"case{i}" for i in range(len(CASES))])
def test_riemann_sample_conserves_mass_momentum_energy(left, right, ref):
    """The sampled solution on [-1, 1] at t: integrals change by t times the boundary fluxes (the waves stay inside)."""
    g = GAMMA
    sol = S.RiemannSolution(left, right, g)
    speeds = [abs(v) for v in sol.shock_speeds() if v is not None]
    speeds += [abs(left[1]) + math.sqrt(g * left[2] / left[0]), abs(right[1]) + math.sqrt(g * right[2] / right[0])]
    t = 0.5 / max(speeds)
    n = 400_000
    x = (np.arange(n) + 0.5) / n * 2 - 1
    rho, u, p = sol.sample(x, t)
    dx = 2.0 / n
    E = p / (g - 1) + 0.5 * rho * u * u

    def flux(r, v, pp):
        return np.array([r * v, r * v * v + pp, (pp / (g - 1) + 0.5 * r * v * v + pp) * v])

    def dens(r, v, pp):
        return np.array([r, r * v, pp / (g - 1) + 0.5 * r * v * v])

    integral = np.array([rho.sum(), (rho * u).sum(), E.sum()]) * dx
    initial = dens(*left) + dens(*right)
    expect = initial + t * (flux(*left) - flux(*right))
    scale = np.abs(initial) + t * (np.abs(flux(*left)) + np.abs(flux(*right))) + 1e-300
    # the waves' end points fall inside sampling cells: the error is O(jump * dx)
    assert np.all(np.abs(integral - expect) <= 2e-4 * scale), (integral, expect)


def test_riemann_refuses_vacuum():
    with pytest.raises(S.VarintError, match="vacuum"):
        S.RiemannSolution((1.0, -10.0, 0.4), (1.0, 10.0, 0.4), GAMMA)


# --- Rankine–Hugoniot ------------------------------------------------------------------------------


def test_generalised_rh_reduces_to_classical_in_a_straight_tube_at_rest():
    """RH_mass, RH_momentum, RH_energy with Gamma = E1, gam = 0 and the same Q are Q times RH_*_0,
    for arbitrary (not jump-satisfying) states; and both vanish across Toro's Sod shock."""
    rng = np.random.default_rng(1)
    for _ in range(20):
        rl, rr, pl, pr = rng.uniform(0.1, 3.0, 4)
        ul, ur, c = rng.uniform(-2, 2, 3)
        R = rng.uniform(0.01, 1.0)
        a = S.ideal_gas_state(rl, ul, pl, GAMMA, R=R)
        b = S.ideal_gas_state(rr, ur, pr, GAMMA, R=R)
        gen = S.rh_residuals(a, b, c)
        cla = S.rh_classical(a, b, c)
        Q = math.pi * R * R
        for k in ("mass", "momentum", "energy"):
            assert gen[k] == pytest.approx(Q * cla[k], rel=1e-12, abs=1e-12 * Q)
    sod = S.RiemannSolution((1.0, 0.0, 1.0), (0.125, 0.0, 0.1), GAMMA)
    a = S.ideal_gas_state(sod.rho_star_right, sod.u_star, sod.p_star, GAMMA, R=0.05)
    b = S.ideal_gas_state(0.125, 0.0, 0.1, GAMMA, R=0.05)
    rel = S.relative_residuals(S.rh_residuals(a, b, sod.shock_speeds()[1]))
    assert max(rel.values()) < 1e-13, rel
    # a wrong speed is seen
    rel = S.relative_residuals(S.rh_residuals(a, b, 1.01 * sod.shock_speeds()[1]))
    assert min(rel.values()) > 1e-3


def test_rh_moving_is_the_general_condition_for_a_traveling_tube():
    """RH_moving (and RH_moving_perfect) equal RH_momentum, RH_energy with gam = -c (Gamma - E1), Q continuous."""
    rng = np.random.default_rng(2)
    for _ in range(10):
        G = rng.normal(size=3) * 0.3 + np.array([1.0, 0.0, 0.0])
        c = rng.uniform(-2, 2)
        gam = -c * (G - np.array([1.0, 0.0, 0.0]))
        sides = [S.ideal_gas_state(r, u, p, GAMMA, R=0.1, Gamma=G, gam=gam)
                 for r, u, p in (rng.uniform(0.2, 2, 3), rng.uniform(0.2, 2, 3))]
        gen = S.rh_residuals(sides[0], sides[1], c)
        Q = sides[0].Q
        for mov in (S.rh_moving(sides[0], sides[1], c), S.rh_moving(sides[0], sides[1], c, gamma=GAMMA)):
            assert -Q * mov["mass"] == pytest.approx(gen["mass"], rel=1e-12, abs=1e-12)
            assert -Q * mov["momentum"] == pytest.approx(gen["momentum"], rel=1e-10, abs=1e-10)
            assert -Q * mov["energy"] == pytest.approx(gen["energy"], rel=1e-10, abs=1e-10)


# --- the traveling shock -----------------------------------------------------------------------------

PAPER = dict(R0=0.05, beta1=1.14e5, beta2=8.37e5, a=0.4782, p_ext=101325.0, rho=1.225, p=101325.0, gamma=1.4)


def _tube(**kw):
    d = dict(PAPER)
    d.update(kw)
    return S.make_tube(**d)


def test_traveling_shock_reproduces_the_papers_rubber_tube():
    """The paper: c ≈ 447 m/s with p_+ ≈ 1.826 atm behind (its quoted beta1, beta2, a)."""
    ts = S.traveling_shock(_tube(), 447.0)
    assert ts.p_plus / 101325.0 == pytest.approx(1.826, rel=6e-3)      # measured 1.8173 (-0.47 %)
    ts2 = S.traveling_shock_of_strength(_tube(), 0.826)
    assert ts2.speed == pytest.approx(447.0, rel=1.5e-2)                 # measured 452.45 (+1.2 %)
    assert ts2.strength == pytest.approx(0.826, rel=1e-10)
    # the far state is uniform and at rest relative to the wall law: beta2 (R+ - R0) = 2 pi R+ (p+ - p_ext)
    assert PAPER["beta2"] * (ts.R_plus - 0.05) == pytest.approx(2 * math.pi * ts.R_plus * (ts.p_plus - 101325.0), rel=1e-12)
    # c* = sqrt(beta1 / a) ≈ 488 m/s, quoted by the paper, bounds the admissible speeds
    lo, hi = S.speed_range(_tube())
    assert lo == pytest.approx(math.sqrt(1.4 * 101325 / 1.225), rel=1e-9)
    assert hi == pytest.approx(488.0, rel=1e-3)


def test_traveling_shock_jumps_satisfy_rh_and_entropy_increases():
    ts = S.traveling_shock(_tube(), 447.0)
    a = S.ideal_gas_state(*ts.ahead, GAMMA, R=ts.R_shock)
    b = S.ideal_gas_state(*ts.behind, GAMMA, R=ts.R_shock)
    rel = S.relative_residuals(S.rh_residuals(b, a, ts.speed))
    assert max(rel.values()) < 1e-12, rel
    assert ts.kappa_plus > ts.kappa_minus
    # the shock is compressive and supersonic into the state just ahead of it
    rho1, u1, p1 = ts.ahead
    assert ts.behind[2] > p1 and abs(u1 - ts.speed) > math.sqrt(GAMMA * p1 / rho1)


def test_traveling_profile_solves_the_wave_equations():
    """R(x), rho, u, p of the profile satisfy Q_cons_wave and meq2_wave pointwise and Req_wave by finite
    differences; R and R' are continuous at the shock; far ahead the gas is at rest, far behind the far state."""
    tb = _tube()
    ts = S.traveling_shock(tb, 447.0)
    c = ts.speed
    x = np.linspace(-1.5, 1.5, 3001)
    R, rho, u, p = ts.profile(x)
    A = math.pi * R * R
    m = rho * (u - c) * A
    assert np.max(np.abs(m / m[-1] - 1)) < 1e-12                               # Q_cons_wave
    g = GAMMA
    B = 0.5 * (u - c) ** 2 + g / (g - 1) * p / rho
    assert np.max(np.abs(B / B[-1] - 1)) < 1e-12                               # meq2_wave (and RH_energy)
    h = 1e-4
    for x0 in (-0.3, -0.05, 0.04, 0.2):
        xs = np.array([x0 - h, x0, x0 + h])
        Rs, _, _, ps = ts.profile(xs)
        Rpp = (Rs[0] - 2 * Rs[1] + Rs[2]) / h ** 2
        res = (tb.beta1 - tb.a * c * c) * Rpp - tb.beta2 * (Rs[1] - tb.R0) + 2 * math.pi * Rs[1] * (ps[1] - tb.p_ext)
        assert abs(res) < 1e-5 * tb.beta2 * (ts.R_plus - tb.R0), (x0, res)  # Req_wave
    Rl, Rr = ts.profile(np.array([-1e-9, 1e-9]))[0]
    assert abs(Rl - Rr) < 1e-9
    vl, vr = ts.wall_velocity(np.array([-1e-9, 1e-9]))
    assert vl == pytest.approx(vr, rel=1e-6)
    assert R[-1] == pytest.approx(tb.R0, abs=1e-7) and abs(u[-1]) < 1e-3
    # behind, the wall relaxes more slowly (decay length about 0.4 m against 0.06 m ahead)
    Rf, _, uf, pf = ts.profile(np.array([-12.0]))
    assert Rf[0] == pytest.approx(ts.R_plus, rel=1e-6) and pf[0] == pytest.approx(ts.p_plus, rel=1e-6)
    assert uf[0] == pytest.approx(ts.u_plus, rel=1e-6)
    assert np.all(np.diff(R) <= 1e-12)                                         # monotone (to the interpolant)


@pytest.mark.parametrize("c", [345.0, 400.0, 480.0])
def test_mach_of_strength_tends_to_the_classical_curve_for_a_rigid_wall(c):
    """M(z) -> sqrt(1 + (gamma+1) z / (2 gamma)) as beta2 -> infinity; the error falls like 1/beta2."""
    errs = []
    for b2 in (1e9, 1e10, 1e11):
        ts = S.traveling_shock(_tube(beta2=b2), c)
        errs.append(abs(ts.mach - S.classical_mach(ts.strength, GAMMA)))
    assert errs[-1] < 2e-5
    assert errs[1] / errs[0] < 0.12 and errs[2] / errs[1] < 0.12


def test_the_tube_changes_the_shock_speed():
    """With the paper's wall M(z) departs from the classical curve (the paper's Figure), by a measured amount."""
    ts = S.traveling_shock(_tube(), 447.0)
    assert ts.mach - S.classical_mach(ts.strength, GAMMA) == pytest.approx(0.00948, abs=5e-4)


def test_admissible_range_errors_name_the_range():
    for c in (300.0, 500.0):
        with pytest.raises(S.ShockError, match=r"admissible range 340\.294 < c < 488\.2"):
            S.traveling_shock(_tube(), c)
    # the material formula for beta1 (436 N) puts c* = 30 m/s below the sound speed: no shock at all
    with pytest.raises(S.ShockError, match="empty"):
        S.traveling_shock(_tube(beta1=436.0), 400.0)


def test_cli_shock(tmp_path, capsys):
    scene = tmp_path / "tube.toml"
    scene.write_text("""title = "paper tube"
[tube]
length = 2.0
nodes = 11
radius = 0.05
[wall]
a = 0.4782
beta1 = 1.14e5
beta2 = 8.37e5
[fluid]
model = "ideal-gas"
density = 1.225
pressure = 101325.0
parcels = 10
[time]
step = 1e-5
end = 1e-4
""")
    assert main(["shock", str(scene), "--speed", "447", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    for k in ("speed", "p_plus", "R_plus", "u_plus", "rho_plus", "R_shock"):
        assert k in d
    assert d["p_plus"] == pytest.approx(S.traveling_shock(_tube(), 447.0).p_plus, rel=1e-12)
    assert main(["shock", str(scene), "--strength", "0.826"]) == 0
    assert "far behind" in capsys.readouterr().out
    assert main(["shock", str(scene), "--speed", "600"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("varint: error:") and "admissible range" in err[0]
    assert main(["shock", str(scene), "--strength", "5"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "outside the admissible range" in err[0]


# --- measuring a shock in a run file ----------------------------------------------------------------


def _write_sod_run(path, M=400, times=(0.1, 0.2), perturb=1.0, wall=True):
    """A run file in the documented layout (docs/output.md) holding the exact Sod solution, cell averages on parcels."""
    sol = S.RiemannSolution((1.0, 0.0, 1.0), (0.125, 0.0, 0.1), GAMMA)
    s = np.linspace(0.0, 1.0, M + 1)
    sub = 64
    fine = (s[:-1, None] + (np.arange(sub) + 0.5)[None, :] / sub * (s[1] - s[0]))
    K = len(times)
    with h5py.File(path, "w") as f:
        f.attrs["records"] = K
        f.attrs["scene_toml"] = '[fluid]\nmodel = "ideal-gas"\ngamma = 1.4\n'
        f["time"] = np.array(times)
        f.create_group("monitors")["energy"] = np.zeros(K)
        g = f.create_group("fields/fluid")
        rho_all, p_all, u_all = [], [], []
        for t in times:
            rho, u, p = sol.sample(fine, t, x0=0.5)
            rho, p = rho.mean(axis=1), p.mean(axis=1)
            rho = np.where(s[:-1] + 0.5 / M < 0.5 + sol.shock_speeds()[1] * t, rho * perturb, rho)
            ul = sol.sample(s, t, x0=0.5)[1]
            rho_all.append(rho), p_all.append(p), u_all.append(ul)
        g["s"] = np.tile(s, (K, 1))
        g["density"] = np.array(rho_all)
        g["pressure"] = np.array(p_all)
        g["velocity"] = np.array(u_all)
        if wall:
            f.create_group("fields/wall")["R"] = np.full((K, 11), 0.05)
    return sol


def test_measure_shock_on_the_exact_sod_solution(tmp_path):
    path = tmp_path / "sod.h5"
    sol = _write_sod_run(path)
    m = measure_shock(path)
    assert m["speed"] == pytest.approx(sol.shock_speeds()[1], rel=2e-3)
    assert m["jumps"]["p"] == pytest.approx(0.1 - sol.p_star, rel=1e-12)
    assert m["jumps"]["R"] == 0.0
    assert max(m["relative"].values()) < 3e-3, m["relative"]
    # a 5 % error in the density behind is seen in the residuals
    bad = tmp_path / "bad.h5"
    _write_sod_run(bad, perturb=1.05)
    assert measure_shock(bad)["relative"]["mass"] > 2e-2


def test_measure_shock_needs_two_records(tmp_path):
    path = tmp_path / "one.h5"
    _write_sod_run(path, times=(0.1,))
    with pytest.raises(S.ShockError, match="record after the first"):
        measure_shock(path)


# --- [initial.traveling_shock] ------------------------------------------------------------------------

SCENE_TS = """title = "traveling shock"
[tube]
length = 2.0
nodes = 201
radius = 0.05
[wall]
model = "{model}"
{a}beta1 = 1.14e5
beta2 = 8.37e5
[fluid]
model = "ideal-gas"
density = 1.225
pressure = 101325.0
parcels = 300
[initial.traveling_shock]
speed = {speed}
position = 0.8
[environment]
external_pressure = 101325.0
[time]
step = 1e-6
end = 5e-6
"""


@pytest.mark.parametrize("model", ["dynamic", "quasistatic"])
def test_initial_traveling_shock_fields_are_the_profile(model):
    """The initial fields (parcel densities and pressures, label velocities, nodal radii) are the
    traveling-wave profile of varint.exact.shocks with the shock at `position`; the scene steps."""
    import varint
    from varint.scene.schema import parse_scene

    text = SCENE_TS.format(model=model, a="a = 0.4782\n" if model == "dynamic" else "", speed=447.0)
    scene = parse_scene(text)
    m = varint.build_model(scene)
    tube = _tube(a=0.4782 if model == "dynamic" else 0.0)
    wave = S.traveling_shock(tube, 447.0)
    R_exp = wave.profile(m.tube.node_s - 0.8)[0]
    assert np.max(np.abs(m.tube.R_reference - R_exp)) < 1e-13
    assert np.max(np.abs(m.tube.R_reference - 0.05)) > 0.01          # the wall is not at rest
    s = np.linspace(0.0, 2.0, m.tube.M + 1)
    centres = 0.5 * (s[:-1] + s[1:])
    _, rho_exp, u_exp, p_exp = wave.profile(centres - 0.8)
    rho = m.tube.m / m.tube.V0
    assert np.max(np.abs(rho / rho_exp - 1)) < 1e-13
    assert np.max(np.abs(m.tube.eos.pressure(rho, m.tube.S) / p_exp - 1)) < 1e-12
    u_lab = wave.profile(s - 0.8)[2]
    assert np.max(np.abs(m.tube.v_init[m.layout["s"]] - u_lab[1:-1])) < 1e-9
    if model == "dynamic":
        # the wall moves with the wave: dR/dt = -c dR/dx, here against central differences of the profile
        dx = 1e-7
        dRdx = (wave.profile(m.tube.node_s - 0.8 + dx)[0] - wave.profile(m.tube.node_s - 0.8 - dx)[0]) / (2 * dx)
        vR = m.tube.v_init[m.layout["R"]]
        assert np.max(np.abs(vR)) > 1.0
        away = np.abs(m.tube.node_s - 0.8) > 2 * dx  # the shock node: R' is continuous but the difference straddles it
        assert np.max(np.abs(vR[away] + 447.0 * dRdx[away])) < 1e-5 * np.max(np.abs(vR))
    sim = varint.make_simulation(m)
    for _ in range(3):
        sim.step()
    assert np.isfinite(sim.monitors()["energy"])


def test_initial_traveling_shock_refuses_what_it_cannot_start():
    from varint.errors import SceneError
    from varint.scene.schema import parse_scene

    with pytest.raises(SceneError, match=r"initial\.traveling_shock\.speed: .*admissible range 340\.294 < c < 488"):
        parse_scene(SCENE_TS.format(model="dynamic", a="a = 0.4782\n", speed=600.0))
    text = SCENE_TS.format(model="dynamic", a="a = 0.4782\n", speed=447.0).replace(
        "[initial.traveling_shock]", "[[fluid.perturbation]]\nfield = \"pressure\"\nshape = \"gaussian\"\namplitude = 1.0\ncenter = 1.0\nwidth = 0.1\n[initial.traveling_shock]")
    with pytest.raises(SceneError, match="replaces the initial fields"):
        parse_scene(text)
    with pytest.raises(SceneError, match=r"initial\.spead: unknown key \(did you mean 'traveling_shock'\?\)|initial.spead"):
        parse_scene(SCENE_TS.format(model="dynamic", a="a = 0.4782\n", speed=447.0) + "[initial.spead]\nx = 1\n")
