"""Linear modes of the coupled tube (varint/analysis/coupled_modes.py; docs/theory.md §10.5, §10.7a), against
independent truths:

* the fluid's static potential: its gradient is -(D1 + D2) of the step kernel at h = 1 with equal levels,
  and its Hessian the second central differences of the potential in the retraction chart (Lambda cay(sigma),
  r + dr, s, R, mu) at a bent, twisted, pressurised state with gravity — gas and liquid;
* the fluid's kinetic metric: v^T M v = sum mbar |Xdot|^2 with Xdot by differences of the centreline;
* the linearisation: M symmetric positive definite, K symmetric, K annihilating the rigid motions of a free
  tube (six zero frequencies);
* §10.7a: a liquid-filled cantilever with labels on the nodes has the bending frequencies of the rod lattice
  with rho A -> rho A + rho_f A_f to round-off (rigid and quasistatic walls, planar and 3D); its axial modes
  are the rod's own (the liquid holds the tube's length); the bending frequencies approach the Timoshenko
  cantilever with that mass at O(ds^2);
* a gas in a very stiff clamped tube: the coupled acoustic modes are the fixed tube's lattice modes, and
  approach n pi c / L at O(ds^2);
* statics (Newton in every block at once): a weakly loaded liquid cantilever sags as the heavy rod, a sagging one
  has the hydrostatic pressure at O(ds^2), a pressurised gas tube stretches by the end caps' thrust exactly and its
  modes about that state are the stretched Timoshenko beam's with the pressure-softened shear, at O(ds^2);
* ``varint modes`` (``--about initial`` and ``static``) on a coupled scene; one-line refusals.
"""

import math
import subprocess
import sys

import numpy as np
import pytest

from varint import build_model, parse_scene
from varint.analysis.linear import modes as tube_modes
from varint.exact.beams import timoshenko_cantilever
from varint.lattice.centreline import centreline
from varint.analysis.coupled_modes import coupled_linearization, coupled_modes, coupled_static, modes_of_linearization
from varint.terms.coupled import FluidPotential, fluid_kinetic_metric, fluid_potential_static, fluid_potential_step
from varint.errors import VarintError
from varint.lattice.lie import cay
from varint.analysis.modes import scene_modes
from varint.analysis.rod_modes import rod_modes
from varint.model.statics import static_equilibrium

from varint.scene.text import to_toml

SECTION = {"mass_per_length": 0.3, "rotary_inertia": 1e-5, "bending_stiffness": 2.0, "torsional_stiffness": 1.6,
           "axial_stiffness": 1e4, "shear_stiffness": 8e3}
GAS = {"model": "ideal-gas", "gamma": 1.4, "density": 1.2, "pressure": 1.0e5}
LIQUID = {"model": "incompressible", "density": 1000.0, "pressure": 1.0e5}
WALL = {"law": "linear", "thickness": 1.0e-3, "density": 1200.0, "youngs_modulus": 5.0e6, "poisson_ratio": 0.45}


def scene_dict(nodes=7, parcels=8, fluid=GAS, wall=None, ends=("clamped", "free"), dimension=2, radius=0.01,
               section=None, length=1.0, gravity=None, velocity=0.0):
    d = {"title": "coupled modes", "tube": {"length": length, "nodes": nodes, "radius": radius},
         "rod": dict(section or SECTION, dimension=dimension, ends={"s0": ends[0], "sL": ends[1]}),
         "fluid": dict(fluid, parcels=parcels, velocity=velocity), "time": {"step": 1e-3, "end": 1.0}}
    if wall is not None:
        d["wall"] = dict(WALL, model=wall)
    if gravity is not None:
        d["environment"] = {"gravity": gravity}
    return d


def model_of(d):
    return build_model(parse_scene(to_toml(d)))


def rod_only(nodes, section, ends, dimension=2, radius=0.01, length=1.0):
    return model_of({"title": "rod", "tube": {"length": length, "nodes": nodes, "radius": radius},
                     "rod": dict(section, dimension=dimension, ends={"s0": ends[0], "sL": ends[1]}),
                     "time": {"step": 1e-3, "end": 1.0}})


def freqs(res):
    return np.array([m["frequency"] for m in res])


# -- the fluid's static potential and metric (varint/terms/coupled.py) -------------------------------------


def _bent_state(fluid, rng):
    """A 3D tube of 4 nodes and 5 parcels moved off its reference state (frames, positions, labels, radii,
    multipliers) with gravity across it and p_ext away from the fluid's pressure."""
    model = model_of(scene_dict(nodes=4, parcels=5, fluid=dict(fluid, pressure=2e5), wall="dynamic", dimension=3,
                                ends=("free", "free")))
    t, rod = model.tube, model.rod
    cfg = t.config(np.concatenate([t.q_init, t.lam_init]))
    g = np.array([0.3, -9.81, 1.0])
    fp = FluidPotential(ds=t.ds, m=t.m, mbar=t.label_mass_all, eos=t.eos, S=t.S if t.eos is not None else None,
                        V0=t.V0 if t.incompressible else None, p_ext=3e4, g=g)
    Lam = rod.Lam0 @ cay(0.3 * rng.standard_normal((rod.N + 1, 3)))
    r = rod.r0 + 0.03 * rng.standard_normal(rod.r0.shape)
    s = cfg.s.copy()
    s[1:-1] += 0.03 * rng.standard_normal(len(s) - 2)
    R = cfg.R * (1 + 0.05 * rng.standard_normal(len(cfg.R)))
    mu = cfg.mu * (1 + 0.1 * rng.standard_normal(len(cfg.mu))) if t.incompressible else None
    return fp, s, r, Lam, R, mu


@pytest.mark.parametrize("fluid", [GAS, LIQUID], ids=["gas", "liquid"])
def test_static_gradient_is_the_step_kernels_at_equal_levels(fluid):
    fp, s, r, Lam, R, mu = _bent_state(fluid, np.random.default_rng(1))
    U, g, _ = fluid_potential_static(fp, s, r, Lam, R, mu, hessian=False)
    st = fluid_potential_step(fp, 1.0, s, r, Lam, R, s, r, Lam, R, mu=mu)
    ref = np.concatenate([-(st.D1.rod + st.D2.rod).ravel(), -(st.D1.s + st.D2.s), -(st.D1.R + st.D2.R)]
                         + ([-st.Dmu] if mu is not None else []))
    assert U == pytest.approx(-st.L, rel=1e-14)
    assert np.max(np.abs(g - ref)) <= 1e-13 * np.max(np.abs(g))


@pytest.mark.parametrize("fluid", [GAS, LIQUID], ids=["gas", "liquid"])
def test_static_hessian_is_the_second_difference_of_the_potential(fluid):
    """H_ij against [U(+i+j) - U(+i-j) - U(-i+j) + U(-i-j)] / (4 e_i e_j) in the chart Lambda cay(sigma), r + dr,
    s, R, mu (end labels are data, not varied): each entry, scaled by typical displacements, to 1e-5 of the
    largest — the pressure's geometric stiffness (p != p_ext here) and gravity included."""
    fp, s, r, Lam, R, mu = _bent_state(fluid, np.random.default_rng(2))
    _, g, H = fluid_potential_static(fp, s, r, Lam, R, mu)
    H = H.toarray()
    nn, nl, nR = len(r), len(s), len(R)
    n = len(g)
    assert np.max(np.abs(H - H.T)) <= 1e-14 * np.max(np.abs(H))

    def U(z):
        u = z[:6 * nn].reshape(nn, 6)
        o = 6 * nn
        mm = mu + z[o + nl + nR:] if mu is not None else None
        return fluid_potential_static(fp, s + z[o:o + nl], r + u[:, :3], Lam @ cay(u[:, 3:]), R + z[o + nl:o + nl + nR],
                                      mm, hessian=False)[0]

    scale = np.concatenate([np.tile([0.01] * 3 + [0.1] * 3, nn), np.full(nl, 0.01), np.full(nR, 1e-3),
                            np.full(n - 6 * nn - nl - nR, 1e3)])
    vary = np.ones(n, bool)
    vary[[6 * nn, 6 * nn + nl - 1]] = False
    e = 3e-3 * scale
    I = np.eye(n)
    idx = np.flatnonzero(vary)
    err = 0.0
    for a, i in enumerate(idx):
        for j in idx[a:]:
            ei, ej = e[i] * I[i], e[j] * I[j]
            fd = (U(ei + ej) - U(ei - ej) - U(-ei + ej) + U(-ei - ej)) / (4 * e[i] * e[j])
            err = max(err, abs(fd - H[i, j]) * scale[i] * scale[j])
    size = np.max(np.abs(H) * scale[:, None] * scale[None, :])
    assert err <= 1e-5 * size


def test_fluid_kinetic_metric_is_the_labels_kinetic_energy():
    """v^T M v = sum_k mbar_k |Xdot_k|^2, Xdot_k = d/dt X(s_k + t sdot_k; r + t rdot) by central differences."""
    rng = np.random.default_rng(3)
    n_nodes, M, ds = 6, 9, 0.2
    r = np.cumsum(np.full((n_nodes, 3), [ds, 0, 0]) + 0.03 * rng.standard_normal((n_nodes, 3)), axis=0)
    s = np.linspace(0.0, (n_nodes - 1) * ds, M + 1)
    s[1:-1] += 0.02 * rng.standard_normal(M - 1)
    mbar = rng.uniform(0.5, 1.5, M + 1)
    Mf, _ = fluid_kinetic_metric(s, r, mbar, ds)
    rdot = rng.standard_normal((n_nodes, 3))
    omega = rng.standard_normal((n_nodes, 3))  # no rotary inertia: must not count
    sdot = rng.standard_normal(M + 1)
    sdot[[0, -1]] = 0.0  # (closed ends: the end labels stay on the end nodes)
    v = np.concatenate([np.concatenate([rdot, omega], axis=1).ravel(), sdot])
    eps = 1e-6
    Xdot = (centreline(s + eps * sdot, r + eps * rdot, ds)[0] - centreline(s - eps * sdot, r - eps * rdot, ds)[0]) / (2 * eps)
    assert v @ (Mf @ v) == pytest.approx(np.sum(mbar * np.sum(Xdot * Xdot, axis=1)), rel=1e-8)


# -- the linearisation ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("fluid,wall", [(GAS, None), (GAS, "dynamic"), (LIQUID, None), (LIQUID, "quasistatic")])
def test_free_tube_mass_is_spd_and_stiffness_annihilates_rigid_motions(fluid, wall):
    """A free straight 3D tube at p = p_ext (an equilibrium): M symmetric positive definite on the inertial
    unknowns, K symmetric, K x = 0 for the six rigid motions (dr = c + zeta x r, sigma = Lambda^T zeta, labels and
    radii unchanged) to 1e-12 of |K| |x|, and the modes start with six zero frequencies, the seventh elastic."""
    model = model_of(scene_dict(nodes=9, parcels=12, fluid=fluid, wall=wall, dimension=3, ends=("free", "free")))
    lin = coupled_linearization(model)
    K, M = lin["K"].toarray(), lin["M"].toarray()
    q = lin["inertial"]
    Mq = M[np.ix_(q, q)]
    assert np.max(np.abs(K - K.T)) <= 1e-14 * np.max(np.abs(K))
    assert np.max(np.abs(Mq - Mq.T)) <= 1e-15 * np.max(np.abs(Mq))
    assert np.min(np.linalg.eigvalsh(Mq)) > 0.0
    assert lin["unbalanced"] < 1e-12
    rod = model.rod
    for k in range(6):
        u = np.zeros((rod.N + 1, 6))
        e = np.eye(3)[k % 3]
        if k < 3:
            u[:, :3] = e
        else:
            u[:, :3] = np.cross(e, rod.r0)
            u[:, 3:] = np.einsum("nji,j->ni", rod.Lam0, e)
        x = np.zeros(model.nz)
        x[model.rod_z] = u[rod.mask]
        assert np.max(np.abs(K @ x)) <= 1e-12 * np.max(np.abs(K)) * np.max(np.abs(x))
    f = freqs(coupled_modes(model, count=model.nz))
    # (zero to the dense solver's resolution, 1e-7 of the highest frequency: varint.analysis.linear)
    assert np.all(f[:6] <= 1e-7 * f[-1]) and f[6] > 1e-4 * f[-1]


def _bending(model, count):
    """The first ``count`` bending frequencies of a planar rod (mode shapes mostly y-displacement)."""
    res, X = rod_modes(model, count=3 * count, vectors=True)
    out = []
    for m, v in zip(res, X.T):
        u = np.zeros((model.rod.N + 1, 6))
        u[model.rod.mask] = v
        if np.sum(u[:, 1] ** 2) > np.sum(u[:, 0] ** 2):
            out.append(m["frequency"])
    return np.array(out[:count])


@pytest.mark.parametrize("wall,dimension", [(None, 2), ("quasistatic", 2), (None, 3)])
def test_liquid_cantilever_bends_as_the_rod_with_the_liquid_mass_to_round_off(wall, dimension):
    """§10.7a: labels on the nodes (M = N), clamped-free, no gravity.  Every bending frequency of the coupled
    lattice is the rod lattice's with rho A + rho_f A_f (rod_modes, an independent code path) to 1e-9: the
    labels stay at rest and the liquid is translational mass only.  In 3D each appears twice."""
    N, R, rho_f = 24, 0.01, 1000.0
    model = model_of(scene_dict(nodes=N + 1, parcels=N, fluid=dict(LIQUID, density=rho_f), wall=wall,
                                dimension=dimension, radius=R))
    heavy = rod_only(N + 1, dict(SECTION, mass_per_length=SECTION["mass_per_length"] + rho_f * math.pi * R * R),
                     ("clamped", "free"), radius=R)
    ref = _bending(heavy, 6)
    f = freqs(coupled_modes(model, count=40))
    for w in ref:
        near = np.sort(np.abs(f - w))
        assert near[0] <= 1e-9 * w
        if dimension == 3:
            assert near[1] <= 1e-9 * w


def test_liquid_in_a_rigid_tube_holds_its_length_axial_modes_are_the_rods_own():
    """Incompressible liquid, rigid wall, closed ends: the parcels' volumes fix the tube's length, so the free end
    cannot move axially and the liquid does not follow the rod's axial motion (it stays at rest while the tube
    stretches past it).  The axial modes are the clamped-clamped rod's with rho A alone (rod_modes), up to the
    lattice's O(ds^2) difference between the parcels' stretched volumes and the tube's spatial length: the first
    within 1e-5, the second 1e-4; the rod with rho A + rho_f A_f (2.5x the mass) is far off."""
    N, R = 30, 0.01
    model = model_of(scene_dict(nodes=N + 1, parcels=N, fluid=LIQUID, radius=R))
    res, X = coupled_modes(model, count=40, vectors=True)
    axial = []
    for m, v in zip(res, X.T):
        u = v[model.rod_z].reshape(-1, 3)  # planar: (dr_x, dr_y, sigma_z) per node (clamped node 0 left out)
        if np.sum(u[:, 0] ** 2) > np.sum(u[:, 1] ** 2):
            axial.append(m["frequency"])
    cc = rod_only(N + 1, SECTION, ("clamped", "clamped"), radius=R)
    res_c, Xc = rod_modes(cc, count=40, vectors=True)
    ref = [m["frequency"] for m, v in zip(res_c, Xc.T) if np.sum(v.reshape(-1, 3)[:, 0] ** 2) > 0.5 * np.sum(v ** 2)]
    assert axial[0] == pytest.approx(ref[0], rel=1e-5)
    assert axial[1] == pytest.approx(ref[1], rel=1e-4)


def test_liquid_cantilever_converges_to_timoshenko_at_second_order():
    """The first two bending frequencies against the Timoshenko cantilever with rho A + rho_f A_f
    (varint.exact.beams.timoshenko_cantilever, shooting): errors fall by ~4 per halving of ds."""
    R, rho_f = 0.01, 1000.0
    m_tot = SECTION["mass_per_length"] + rho_f * math.pi * R * R
    truth = timoshenko_cantilever(SECTION["bending_stiffness"], SECTION["shear_stiffness"], m_tot,
                                  SECTION["rotary_inertia"], 1.0, count=2)
    errs = []
    for N in (15, 30, 60):
        model = model_of(scene_dict(nodes=N + 1, parcels=N, fluid=dict(LIQUID, density=rho_f), radius=R))
        f = freqs(coupled_modes(model, count=20))
        errs.append([np.min(np.abs(f - w)) / w for w in truth])
    errs = np.array(errs)
    order = np.log2(errs[:-1] / errs[1:])
    assert np.all(errs[-1] < 2e-4)
    assert np.all((order > 1.8) & (order < 2.3)), order


def test_gas_in_a_stiff_clamped_tube_has_the_fixed_tubes_acoustic_modes():
    """A gas-filled tube clamped at both ends, rod 10^4 times stiffer axially than the gas column: its axial
    acoustic frequencies are the fixed straight tube's lattice modes (varint.analysis.linear.modes, the 0.1 code path)
    to 1e-8, and approach n pi c / L at second order in the parcel length."""
    c = math.sqrt(GAS["gamma"] * GAS["pressure"] / GAS["density"])
    stiff = dict(SECTION, axial_stiffness=1e8, shear_stiffness=1e8, bending_stiffness=1e5, torsional_stiffness=1e5,
                 mass_per_length=0.5, rotary_inertia=1e-4)
    errs = []
    for M in (20, 40):
        model = model_of(scene_dict(nodes=21, parcels=M, fluid=GAS, section=stiff, ends=("clamped", "clamped")))
        f = freqs(coupled_modes(model, count=60))
        fixed = model_of({"title": "fixed tube", "tube": {"length": 1.0, "nodes": 21, "radius": 0.01},
                          "fluid": dict(GAS, parcels=M), "time": {"step": 1e-4, "end": 1.0}})
        ref = freqs(tube_modes(fixed, count=4))
        ac = np.array([f[np.argmin(np.abs(f - w))] for w in ref])
        assert np.max(np.abs(ac - ref) / ref) < 1e-8
        errs.append(np.abs(ac - np.arange(1, 5) * math.pi * c) / ac)
    order = np.log2(errs[0] / errs[1])
    assert np.all((order > 1.9) & (order < 2.1)), order


@pytest.mark.parametrize("fluid,wall", [(GAS, "dynamic"), (LIQUID, None), (LIQUID, "quasistatic")])
def test_sparse_solver_gives_the_dense_modes(fluid, wall):
    """Shift-invert Lanczos on the whole pencil (K, M), M singular on the multipliers and quasistatic radii, gives the
    dense solver's lowest modes (condensed, constraints on their null space) of a clamped tube with more parcels
    than nodes, to 1e-7."""
    model = model_of(scene_dict(nodes=16, parcels=21, fluid=fluid, wall=wall, dimension=3))
    fd = freqs(coupled_modes(model, count=12, method="dense"))
    fs = freqs(coupled_modes(model, count=12, method="sparse"))
    assert np.max(np.abs(fs - fd) / fd) < 1e-7


# -- statics, and modes about them ------------------------------------------------------------------------


def test_liquid_cantilever_sags_as_the_rod_with_the_liquid_mass():
    """Static equilibrium under a weak gravity (tip deflection 4e-4 L): the tip of the liquid-filled cantilever
    (labels on the nodes) is the heavy rod's (rod_statics.static_equilibrium with rho A + rho_f A_f) to 1e-6 of the
    deflection — the difference is second order in the load — and the state is balanced to round-off."""
    N, R, rho_f = 20, 0.01, 1000.0
    g = [0.0, -0.01, 0.0]
    model = model_of(scene_dict(nodes=N + 1, parcels=N, fluid=dict(LIQUID, density=rho_f), radius=R, gravity=g))
    (Lam, r, zt), info = coupled_static(model)
    heavy = model_of({"title": "heavy rod", "tube": {"length": 1.0, "nodes": N + 1, "radius": R},
                      "rod": dict(SECTION, mass_per_length=SECTION["mass_per_length"] + rho_f * math.pi * R * R,
                                  dimension=2, ends={"s0": "clamped", "sL": "free"}),
                      "environment": {"gravity": g}, "time": {"step": 1e-3, "end": 1.0}})
    _, rh, _ = static_equilibrium(heavy)
    assert np.linalg.norm(r[-1] - rh[-1]) <= 1e-6 * np.linalg.norm(rh[-1] - [1.0, 0.0, 0.0])
    assert coupled_linearization(model, (Lam, r, zt))["unbalanced"] < 1e-12


@pytest.mark.parametrize("wall", [None, "quasistatic"])
def test_sagging_liquid_cantilever_has_the_hydrostatic_pressure(wall):
    """Under full gravity (tip 0.34 L down) the multipliers are the hydrostatic law p_k - p_0 = rho_f g . (c_k - c_0),
    c_k the centre of parcel k on the computed centreline, at second order in ds (errors 1.2e-3 / 3.2e-4 rigid,
    1.0e-3 / 2.3e-4 quasistatic at 20 / 40 elements)."""
    g = np.array([0.0, -9.81, 0.0])
    errs = []
    for N in (20, 40):
        model = model_of(scene_dict(nodes=N + 1, parcels=N, fluid=LIQUID, wall=wall, gravity=list(g)))
        (Lam, r, zt), _ = coupled_static(model)
        cfg = model.tube.config(zt)
        c = centreline(0.5 * (cfg.s[:-1] + cfg.s[1:]), r, model.tube.ds)[0]
        pred = LIQUID["density"] * (c - c[0]) @ g
        errs.append(np.max(np.abs((cfg.mu - cfg.mu[0]) - pred)) / np.max(np.abs(pred)))
    assert errs[1] < 5e-4 and math.log2(errs[0] / errs[1]) > 1.8


@pytest.mark.slow  # 0.4-0.8 min: the slow tier (tests/conftest.py; CI runs it)
def test_pressurised_gas_tube_prestretch_and_modes_about_it():
    """A closed clamped-free tube of gas at p_0 = 2 bar in 1 bar outside.  Static: the rod stretches uniformly by
    eps, EA eps = (p_0 (1 + eps)^-gamma - p_ext) A (the end caps' thrust; scalar root), to 1e-12.  Modes about that
    state (docs/theory.md §10.7a): the end-cap thrust and the wall tension cancel (zero effective tension) and the
    pressure softens the shear, so the bending frequencies are the Timoshenko cantilever's with kGA - Delta p A/(1+eps),
    EI and rho I divided by (1 + eps)^2 (the shear strain of the stretched rod is w' - (1 + eps) theta), and the mass
    rho A + rho_gas A per reference length — at O(ds^2); the plain Timoshenko beam is 2-3 % off."""
    from scipy.optimize import brentq

    R = 0.01
    A = math.pi * R * R
    sec = dict(SECTION, shear_stiffness=200.0, axial_stiffness=2000.0)
    p0, p_ext = 2.0e5, 1.0e5
    eps = brentq(lambda e: sec["axial_stiffness"] * e - (p0 * (1 + e) ** -GAS["gamma"] - p_ext) * A, -0.5, 0.5)
    dpA = (p0 * (1 + eps) ** -GAS["gamma"] - p_ext) * A
    truth = timoshenko_cantilever(sec["bending_stiffness"] / (1 + eps) ** 2, sec["shear_stiffness"] - dpA / (1 + eps),
                                  sec["mass_per_length"] + GAS["density"] * A, sec["rotary_inertia"] / (1 + eps) ** 2,
                                  1.0, count=2)
    plain = timoshenko_cantilever(sec["bending_stiffness"], sec["shear_stiffness"], sec["mass_per_length"],
                                  sec["rotary_inertia"], 1.0, count=2)
    errs = []
    for N in (20, 40):
        d = scene_dict(nodes=N + 1, parcels=N, fluid=dict(GAS, pressure=p0), radius=R, section=sec)
        d["environment"] = {"external_pressure": p_ext}
        model = model_of(d)
        (Lam, r, zt), _ = coupled_static(model)
        assert np.max(np.abs(r[:, 0] - np.linspace(0.0, 1.0 + eps, N + 1))) <= 1e-12
        f = freqs(modes_of_linearization(model, coupled_linearization(model, (Lam, r, zt)), 4))[:2]
        errs.append(np.abs(f - truth) / truth)
        assert np.all(np.abs(f - plain) / plain > 0.015)
    assert np.all(errs[1] < 3e-4) and np.all(np.log2(errs[0] / errs[1]) > 1.9)


def test_free_coupled_tube_has_no_static_equilibrium_one_line():
    with pytest.raises(VarintError, match="no unique static equilibrium"):
        coupled_static(model_of(scene_dict(ends=("free", "free"))))


# -- varint modes -------------------------------------------------------------------------------------------


def test_scene_modes_of_a_coupled_scene_notes_an_unbalanced_initial_state():
    """scene_modes answers for a coupled scene; with gravity the initial state is not in equilibrium and the
    answer says so (the rod's rule); without, no note."""
    d = scene_dict(nodes=11, parcels=10, fluid=LIQUID, wall="quasistatic")
    out = scene_modes(parse_scene(to_toml(d)), count=4, source="hose")
    assert len(out["modes"]) == 4 and "note" not in out and out["about"] == "initial"
    d["environment"] = {"gravity": [0.0, -9.81, 0.0]}
    out = scene_modes(parse_scene(to_toml(d)), count=4, source="hose")
    assert "environment.gravity" in out["note"]
    static = scene_modes(parse_scene(to_toml(d)), count=4, about="static", source="hose")
    assert static["about"] == "static" and "note" not in static
    # the sagging hose's first frequency differs from the straight one's (the weight's geometric stiffness)
    assert static["modes"][0]["frequency"] != pytest.approx(out["modes"][0]["frequency"], rel=1e-6)


def test_flowing_fluid_is_refused_in_one_line():
    with pytest.raises(VarintError, match="fluid must not flow"):
        coupled_modes(model_of(scene_dict(fluid=GAS, velocity=1.0)))
    # a liquid cannot flow in a closed rigid tube at all: the scene is refused (issue 24)
    with pytest.raises(VarintError, match="fluid.velocity: 1 m/s: an incompressible liquid in a closed, rigid tube"):
        model_of(scene_dict(fluid=LIQUID, velocity=1.0))
    with pytest.raises(VarintError, match="fluid must not flow"):
        coupled_modes(model_of(scene_dict(fluid=LIQUID, wall="quasistatic", velocity=1.0)))


def test_cli_modes_of_the_water_filled_hose(tmp_path):
    """``varint modes`` on the example: the first frequency is the hose's first bending mode, within 5 % of
    Euler-Bernoulli with the rubber's and the water's mass (a slender hose)."""
    from pathlib import Path

    from varint.exact.beams import euler_bernoulli_cantilever

    scene = Path(__file__).resolve().parent.parent / "examples" / "water_filled_hose.toml"
    out = subprocess.run([sys.executable, "-m", "varint", "modes", str(scene), "-n", "3"], capture_output=True,
                         text=True, cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    w1 = float(out.stdout.split()[2])
    Ro, Ri, E, rho = 0.008 + 0.002, 0.008, 5.0e6, 1100.0
    EI = E * math.pi * (Ro ** 4 - Ri ** 4) / 4
    m = rho * math.pi * (Ro ** 2 - Ri ** 2) + 1000.0 * math.pi * Ri ** 2
    assert w1 == pytest.approx(euler_bernoulli_cantilever(EI, m, 1.0, 1)[0], rel=0.05)
