"""The inextensible, unshearable rod (docs/theory.md §9a, varint/terms/rod_constraint.py).

* its step residual (with the constraint rows) is the gradient of the discrete action, its Newton Jacobian
  the derivative of the residual (central differences);
* Gamma = chi holds at every level to round-off, the momenta of a free rod are conserved to round-off,
  and the energy (the momenta projected on the constraint, as RATTLE) shows no jump and no drift;
* outside truth: a cantilever's first bending frequency is the Rayleigh beam's (Euler–Bernoulli with
  rotary inertia, varint.exact.beams.timoshenko_cantilever with an unshearable section) to O(ds^2);
* the hard case of docs/theory.md §12: a rubber hose that the shearable rod cannot step at h = 2 ms (the
  resonance instability of its shear–rotation modes) runs stably with the constraint, with and without
  the water in it.
"""

import math
from pathlib import Path

import numpy as np
import pytest

from varint import Simulation, build_model, parse_scene
from varint.exact.beams import timoshenko_cantilever
from varint.lattice.lie import cay
from varint.terms.rod import pack_level, unpack_level

from helpers import momentum_drift, tip_frequency
from varint.scene.standard import ROD_SECTION as SECTION, rod_scene

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


def constrained(scene):
    scene.rod["constraint"] = "inextensible_unshearable"
    return build_model(scene)


CASES = {
    "free-3d-bent-spinning": dict(initial={"curvature": [0.3, 1.0, 0.5], "angular_velocity": [0.0, 0.0, 3.0]},
                                  gravity=[0.0, -9.81, 0.0]),
    "clamped-3d-loaded": dict(ends=("clamped", "free"), initial={"curvature": [0.0, 1.0, 0.5]},
                              load={"force": [0.0, -1.0, 0.5]}),  # (a torque is not in the action: tests/test_forces.py)
    "pinned-planar": dict(ends=("pinned", "free"), dimension=2, initial={"curvature": [0.0, 0.0, 1.5]},
                          gravity=[0.0, -9.81, 0.0]),
}


def _move(model, q, rng, amp):
    q = q.copy()
    Lam, r, o = unpack_level(q[model.rod_q], model.N)
    mask = model.rod.mask
    q[model.rod_q] = pack_level(Lam @ cay(amp * rng.standard_normal(r.shape) * mask[:, 3:]),
                                r + amp * model.ds * rng.standard_normal(r.shape) * mask[:, :3], o)
    return q


@pytest.mark.parametrize("case", list(CASES))
def test_residual_is_the_gradient_of_the_action_and_the_jacobian_its_derivative(case):
    model = constrained(rod_scene(nodes=7, h=1e-2, **CASES[case]))
    rod, N = model.rod, model.N
    sim = Simulation(model)
    step = sim.stepper.action
    rng = np.random.default_rng(3)
    q0 = sim.state.q
    q1 = _move(model, q0, rng, 0.05)
    q2 = _move(model, q1, rng, 0.05)
    lam1, lam2 = (rng.standard_normal(rod.nlam) for _ in range(2))
    p1 = step.momentum_plus(q0, step.unknowns(q0, q1, lam1))
    z12 = step.unknowns(q1, q2, lam2)
    res = step.residual(q1, p1, z12)

    def action(q, lam=lam2):
        return step.discrete_lagrangian(q0, q, lam1) + step.discrete_lagrangian(q, q2, lam)

    Lam1, r1, o1 = unpack_level(q1[model.rod_q], N)
    full = np.zeros((N + 1, 6))
    full[rod.mask] = res[model.rod_z]
    full[:, :3] = np.einsum("nij,nj->ni", Lam1, full[:, :3])
    got, fd = [], []
    for j in range(N + 1):
        for d in range(6):
            if not rod.mask[j, d]:
                continue
            e = np.zeros(3)
            e[d % 3] = 1.0
            eps = 1e-6 * (model.ds if d < 3 else 1.0)
            vals = []
            for sgn in (1, -1):
                L, r = Lam1.copy(), r1.copy()
                if d < 3:
                    r[j] += sgn * eps * e
                else:
                    L[j] = L[j] @ cay(sgn * eps * e)
                q = q1.copy()
                q[model.rod_q] = pack_level(L, r, o1)
                vals.append(action(q))
            got.append(full[j, d])
            fd.append((vals[0] - vals[1]) / (2 * eps))
    got, fd = np.array(got), np.array(fd)
    assert np.allclose(got, fd, rtol=0, atol=1e-6 * np.abs(fd).max()), np.abs(got - fd).max() / np.abs(fd).max()
    # the constraint rows (SHAKE, theory §9a): D_lambda of the NEXT step's term at q2, -h ds (Gamma(q2) - chi);
    # L_d is linear in lambda: exact differences; q3 is any level after q2 (the term reads q2 alone)
    Dl = res[model.rod_lam_z]
    q3 = _move(model, q2, rng, 0.05)
    fdl = np.empty(rod.nlam)
    for i in range(rod.nlam):
        e = np.zeros(rod.nlam)
        e[i] = 1.0
        fdl[i] = (step.discrete_lagrangian(q2, q3, lam2 + e) - step.discrete_lagrangian(q2, q3, lam2 - e)) / 2.0
    assert np.abs(fdl).max() > 1e-6  # q2 is off the constraint: the rows are not trivially zero
    assert np.allclose(Dl, fdl, rtol=0, atol=1e-9 * np.abs(fdl).max())
    # Jacobian against differences of the residual, columns scaled by the unknowns' scales, per row block
    J = step.jacobian(q1, z12).toarray()
    Jfd = np.empty_like(J)
    for i in range(model.nz):
        e = np.zeros(model.nz)
        e[i] = 1e-6 * sim.stepper.scale[i]
        Jfd[:, i] = (step.residual(q1, p1, z12 + e) - step.residual(q1, p1, z12 - e)) / (2 * e[i])
    for rows in (model.rod_z, model.rod_lam_z):
        A, B = J[rows] * sim.stepper.scale, Jfd[rows] * sim.stepper.scale
        assert np.allclose(A, B, rtol=0, atol=1e-6 * np.abs(B).max()), np.abs(A - B).max() / np.abs(B).max()


def test_constraint_momenta_and_energy_of_a_free_spinning_rod():
    """Gamma = chi at every level to round-off; P, J to round-off; the energy of the projected momenta is
    continuous from the initial data and bounded (no drift between the first and last thirds)."""
    model = constrained(rod_scene(nodes=11, h=1e-3, initial={"curvature": [0.0, 1.0, 0.5], "angular_velocity": [0.0, 0.0, 3.0]}))
    sim = Simulation(model)
    m0 = sim.monitors()
    assert m0["rod_constraint_residual"] < 1e-14
    E = [m0["energy"]]
    for _ in range(600):
        sim.step()
        mo = sim.monitors()
        E.append(mo["energy"])
        assert mo["rod_constraint_residual"] < 1e-12
        # round-off: |J| = 0.064, sqrt(2 m E) = 0.9 here; the level force h G(q_n)^T lambda_n sums to zero up to
        # round-off of its terms (measured 9e-14 / 5.5e-14 after 600 steps, a random walk)
        assert np.allclose(mo["linear_momentum"], m0["linear_momentum"], rtol=0, atol=2e-13)
        assert np.allclose(mo["angular_momentum"], m0["angular_momentum"], rtol=0, atol=2e-13)
    E = np.array(E) - E[0]
    assert abs(E[1]) < 1e-3 * abs(m0["energy"])  # no jump from the initial data to the first step
    assert np.max(np.abs(E)) < 5e-3 * abs(m0["energy"])
    assert abs(np.mean(E[-200:]) - np.mean(E[1:201])) < 0.3 * np.max(np.abs(E))


@pytest.mark.parametrize("scheme", ["midpoint", "energy-momentum"])
def test_cantilever_frequency_is_the_rayleigh_beam_s(scheme):
    """Released at rest from a small static tip deflection: the tip oscillates at the first bending
    frequency of the unshearable beam with rotary inertia (Timoshenko's shooting at kGA = 1e7, within 4e-7
    of its unshearable limit; Euler–Bernoulli without the rotary inertia is 7.6e-5 higher), to the lattice's
    O(ds^2) (measured: -6.6e-4, -1.8e-4 at 20, 40 elements, both schemes alike to 10 digits), once the midpoint rule's own frequency
    shift (2/h) atan(w h/2) is undone (the energy-momentum step of docs/theory.md §12a, the same rule on a
    quadratic energy, shifts it alike)."""
    errs = []
    sec = dict(SECTION, mass_per_length=0.3, bending_stiffness=2.0, rotary_inertia=1e-5)
    beam = timoshenko_cantilever(sec["bending_stiffness"], 1e7, sec["mass_per_length"], sec["rotary_inertia"], 1.0, count=1)[0]
    for N in (20, 40):
        from varint.model.statics import static_equilibrium

        # a starting shape close to the first mode: the static deflection under a tiny tip load
        # (of the constrained rod: the energy-momentum step asks Gamma = chi of its initial data)
        loaded = constrained(rod_scene(nodes=N + 1, ends=("clamped", "free"), dimension=2, section=sec,
                                       load={"force": [0.0, -1e-4, 0.0]}))
        Lam, r, _ = static_equilibrium(loaded)
        model = constrained(rod_scene(nodes=N + 1, h=4e-3, ends=("clamped", "free"), dimension=2, section=sec))
        model.rod.set_configuration(Lam, r, rest=True)
        f = tip_frequency(model, 800, scheme=scheme)
        # the midpoint rule turns a frequency w into (2/h) atan(w h/2) (-1.1e-4 here): undo it to see the lattice's
        h = model.scene.time.step
        errs.append((2.0 / h) * math.tan(0.5 * f * h) / beam - 1)
    assert abs(errs[1]) < 1e-3 and abs(errs[1]) < abs(errs[0])
    order = math.log(abs(errs[0] / errs[1]), 2)
    assert 1.5 < order < 2.5, (errs, order)


@pytest.mark.parametrize("with_water", [False, True])
def test_the_hose_that_the_shearable_rod_cannot_step_runs_with_the_constraint(with_water):
    """docs/theory.md §12: the rubber hose of examples/water_filled_hose.toml at h = 2 ms.  The shearable rod
    dies (a node turning by more than 90 degrees in one step, after the energy grew); the constrained rod
    runs the same 700 steps with its energy bounded."""
    text = (EXAMPLES / "water_filled_hose.toml").read_text().replace("step = 1.0e-3", "step = 2.0e-3")
    text = text.replace('scheme = "energy-momentum"', 'scheme = "midpoint"')
    if not with_water:
        a, b = text.index("[wall]"), text.index("[environment]")
        text = text[:a] + text[b:]
    from varint.errors import SolverError

    free = Simulation(build_model(parse_scene(text)))
    with pytest.raises(SolverError, match="turns by|labels|Newton failed"):
        for _ in range(900):
            free.step()
    scene = parse_scene(text)
    model = constrained(scene)
    sim = Simulation(model)
    E0 = sim.monitors()["energy"]
    worst = 0.0
    for _ in range(700):
        sim.step()
        mo = sim.monitors()
        worst = max(worst, abs(mo["energy"] - E0))
        assert mo["rod_constraint_residual"] < 1e-10
    swing = float(np.sum(model.rod.node_mass)) * 9.81 * 1.0  # the scale of the potential energy exchanged
    assert worst < 2e-2 * swing


def test_the_stiff_band_case_of_the_diagnosis_runs_with_the_constraint():
    """docs/theory.md §12, case A: PyElastica's benchmark section (r = 1 cm, E = 1 MPa), free, released from an
    arc of curvature 2 /m while spinning at 2 rad/s, planar, 50 elements, h = 5 ms (0.01 rad of spin per step).
    The shearable rod's energy explodes (|dE| > 10 E0 by step 390: the resonance of its unresolved
    shear-rotation modes); with the constraint the same 450 steps keep the energy within 1 % (measured 1.4e-3)."""
    E, rho, r = 1e6, 1000.0, 0.01
    A, I = math.pi * r * r, math.pi * r ** 4 / 4
    sec = dict(mass_per_length=rho * A, rotary_inertia=rho * I, bending_stiffness=E * I, torsional_stiffness=E / 1.5 * 2 * I,
               axial_stiffness=E * A, shear_stiffness=4 / 3 * E / 1.5 * A)
    kw = dict(nodes=51, h=5e-3, dimension=2, section=sec, initial={"curvature": [0.0, 0.0, 2.0], "angular_velocity": [0.0, 0.0, 2.0]})
    from varint.errors import SolverError

    free = Simulation(build_model(rod_scene(**kw)))
    E0 = free.monitors()["energy"]
    blew_up = False
    try:
        for _ in range(450):
            free.step()
            if abs(free.monitors()["energy"] / E0 - 1) > 10:
                blew_up = True
                break
    except SolverError:
        blew_up = True
    assert blew_up
    sim = Simulation(constrained(rod_scene(**kw)))
    E0 = sim.monitors()["energy"]
    worst = 0.0
    for _ in range(450):
        sim.step()
        worst = max(worst, abs(sim.monitors()["energy"] / E0 - 1))
    assert worst < 1e-2


def test_static_elastica_and_modes_of_the_constrained_rod_at_second_order():
    """Statics (Newton on the KKT system with the constraint's geometric stiffness) against the inextensible
    elastica under a dead tip load P L^2/EI = 4 (tip rotation 64 degrees), and modes (the stiffness on the
    constraint's null space) against the unshearable beam with rotary inertia: both at order 2 (measured
    tip errors 1.2e-3, 2.9e-4, 7.3e-5 at 20 / 40 / 80 elements; first frequency -6.6e-4, -1.7e-4)."""
    from varint.exact.beams import elastica_cantilever_tip
    from varint.analysis.modes import scene_modes
    from varint.model.statics import static_equilibrium

    EI = 2.0
    sec = dict(SECTION, mass_per_length=0.3, bending_stiffness=EI, rotary_inertia=1e-5)
    xe, ye, _ = elastica_cantilever_tip(4 * EI, EI, 1.0)
    beam = timoshenko_cantilever(EI, 1e7, sec["mass_per_length"], sec["rotary_inertia"], 1.0, count=1)[0]
    tip, freq = [], []
    for N in (20, 40, 80):
        loaded = rod_scene(nodes=N + 1, dimension=2, section=sec, ends=("clamped", "free"), load={"force": [0.0, -4 * EI, 0.0]})
        model = constrained(loaded)
        Lam, r, info = static_equilibrium(model)
        tip.append(np.linalg.norm(r[-1, :2] - [xe, ye]))
        assert np.max(np.abs(model.rod.strains(Lam, r)[1] - [1.0, 0.0, 0.0])) < 1e-10
        free = rod_scene(nodes=N + 1, dimension=2, section=sec, ends=("clamped", "free"))
        free.rod["constraint"] = "inextensible_unshearable"
        freq.append(scene_modes(free, count=1)["modes"][0]["frequency"] / beam - 1)
    for errs in (tip, freq):
        orders = [math.log(abs(errs[i] / errs[i + 1]), 2) for i in range(2)]
        assert all(1.8 < o < 2.2 for o in orders), (errs, orders)
    # about the loaded equilibrium (--about static) the element forces' geometric stiffness enters
    about = scene_modes(loaded, count=1, about="static")["modes"][0]["frequency"]
    assert about > 0 and abs(about / (beam * (1 + freq[-1])) - 1) > 1e-3


def test_what_the_constrained_rod_cannot_do_yet_is_refused_in_one_line():
    """A straight rod held at both ends has an indeterminate tension (its Newton matrix is singular); a
    steady rotation needs the constraint in the rotating statics."""
    from varint.errors import SceneError

    held = rod_scene(nodes=7, ends=("pinned", "pinned"))
    held.rod["constraint"] = "inextensible_unshearable"
    with pytest.raises(SceneError, match="indeterminate tension"):
        build_model(held)
    bent = rod_scene(nodes=7, ends=("pinned", "pinned"), initial={"curvature": [0.0, 0.0, 1.0]})
    bent.rod["constraint"] = "inextensible_unshearable"
    sim = Simulation(build_model(bent))
    sim.step()
    assert sim.monitors()["rod_constraint_residual"] < 1e-12


def test_constraint_static_blocks_are_the_derivative_of_the_constraint_force():
    """_k_constraint_static_blocks (the geometric stiffness of the element forces) against central differences
    of the constraint force -ds G^T lam at a bent, twisted 3D state with random element forces; and G against
    differences of the strains."""
    from varint.terms.rod import banded_jacobian
    from varint.terms.rod_constraint import constraint_static
    from varint.model.statics import retract

    model = constrained(rod_scene(nodes=8, ends=("clamped", "free"), initial={"curvature": [0.4, 1.0, -0.6]}))
    rod = model.rod
    rng = np.random.default_rng(9)
    lam = rng.standard_normal((rod.N, 3))
    Lam, r = rod.Lam0 @ cay(0.1 * rng.standard_normal((rod.N + 1, 3))), rod.r0 + 0.01 * rng.standard_normal((rod.N + 1, 3))
    c, G, F, H = constraint_static(rod, Lam, r, lam)

    def force(z):
        Lz, rz = retract(Lam, r, z, rod.mask)
        out = np.zeros((rod.N + 1, 6))
        out[rod.mask] = constraint_static(rod, Lz, rz, lam)[2]
        return out

    Hfd = banded_jacobian(force, np.zeros(rod.nz), rod.mask, rod.ds).toarray()
    assert np.max(np.abs(H.toarray() - Hfd)) < 1e-6 * np.max(np.abs(Hfd))

    def strains(z):
        Lz, rz = retract(Lam, r, z, rod.mask)
        return (rod.strains(Lz, rz)[1] - [1.0, 0.0, 0.0]).ravel()

    Gfd = np.empty((len(c), rod.nz))
    for i in range(rod.nz):
        e = np.zeros(rod.nz)
        e[i] = 1e-7
        Gfd[:, i] = (strains(e) - strains(-e)) / 2e-7
    assert np.max(np.abs(G.toarray() - Gfd)) < 1e-6 * np.max(np.abs(Gfd))


def test_free_constrained_rod_keeps_its_momenta_to_round_off_over_1000_steps():
    """theory §9a/§10.6, "Momenta to round-off" in the general Step path: the free spinning bent rod of the test above,
    1000 steps at h = 1 ms.  Measured max (every 10th step) |dP| L/|J0|, |dJ|/|J0|: 1.2e-14, 7.0e-15; before the
    element kernels read the increments and the step was polished along the rigid motions: 2.0e-12, 1.2e-12."""
    model = constrained(rod_scene(nodes=11, h=1e-3, initial={"curvature": [0.0, 1.0, 0.5], "angular_velocity": [0.0, 0.0, 3.0]}))
    sim = Simulation(model)
    dP, dJ = momentum_drift(sim, 1000, every=10)
    assert dP < 1e-13 and dJ < 5e-14, (dP, dJ)
