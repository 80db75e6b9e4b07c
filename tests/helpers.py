"""Helpers the tests share (the standard scenes themselves are varint.scene.standard's)."""

import numpy as np

from varint import Simulation, build_model, parse_scene
from varint.analysis.signals import zero_crossing_frequency
from varint.lattice.lie import cay
from varint.scene.standard import liquid_cantilever_scenes
from varint.scene.text import to_toml


def make(d):
    """Scene dict -> (scene, model)."""
    scene = parse_scene(to_toml(d))
    return scene, build_model(scene)


def tip_frequency(model, steps, scheme=None):
    """Angular frequency of a rod's tip motion in y over ``steps`` steps, from its zero crossings."""
    sim = Simulation(model, scheme=scheme)
    t, y = np.empty(steps), np.empty(steps)
    for i in range(steps):
        sim.step()
        t[i], y[i] = sim.state.t, sim.fields()["rod/r"][-1, 1]
    return zero_crossing_frequency(t, y)


def momentum_drift(sim, steps, every=1):
    """Largest changes of a Simulation's momenta over ``steps`` steps (monitors every ``every`` steps):
    (max |P - P0| L / |J0|, max |J - J0| / |J0|)."""
    m0 = sim.monitors()
    P0, J0 = m0["linear_momentum"], m0["angular_momentum"]
    scale = np.linalg.norm(J0)
    dP = dJ = 0.0
    for n in range(steps):
        sim.step()
        if n % every == every - 1:
            mo = sim.monitors()
            dP = max(dP, np.abs(mo["linear_momentum"] - P0).max() * sim.model.L / scale)
            dJ = max(dJ, np.abs(mo["angular_momentum"] - J0).max() / scale)
    return dP, dJ


def fail_newton_at(step, sizes, calls=None, after=0):
    """Make an energy-momentum step's Newton (``step._solve``) fail while the step size is one of ``sizes``: the
    attempts at each size numbered after+1 .. calls (counted from 1; ``calls=None``: all from after+1 on).  With
    after=0 and calls = the starts tried before varint.schemes.em_rod.halved_step, only those fail.  Attempts at other step
    sizes run as usual.  Returns the list of the sizes attempted."""
    from varint.errors import SolverError

    real, seen = step._solve, []
    sizes = np.atleast_1d(sizes).tolist()

    def solve(z, chord):
        seen.append(step.h)
        c = seen.count(step.h)
        if step.h in sizes and c > after and (calls is None or c <= calls):
            raise SolverError(f"step {step.n + 1}: induced failure")
        return real(z, chord)

    step._solve = solve
    return seen


def _release_from_mode(model, shape_of, amp=1e-4):
    """Start ``model``'s rod at rest in the first mode shape of ``shape_of`` (a rod model), tip amplitude ``amp``."""
    from varint.analysis.rod_modes import rod_modes

    _, X = rod_modes(shape_of, count=1, vectors=True)
    rod = model.rod
    u = np.zeros((model.N + 1, 6))
    u[rod.mask] = X[:, 0]
    u *= amp / np.max(np.abs(u[:, :3]))
    rod.set_configuration(rod.Lam0 @ cay(u[:, 3:]), rod.r0 + u[:, :3], rest=True)


def liquid_cantilever(N, h, R=0.01, L=1.0, rho_f=1000.0, scheme="midpoint"):
    """The water-filled cantilever of docs/theory.md §10.7a and the rod lattice with the liquid's mass rho_f A_f added
    to rho A (varint.scene.standard.liquid_cantilever_scenes), both released from the latter's first mode.  Returns
    (coupled, heavy, Timoshenko's first frequency with that mass)."""
    from varint.exact.beams import timoshenko_cantilever

    coupled_scene, heavy_scene = liquid_cantilever_scenes(N, h, R=R, L=L, rho_f=rho_f, scheme=scheme)
    coupled, heavy = build_model(coupled_scene), build_model(heavy_scene)
    _release_from_mode(heavy, heavy)
    _release_from_mode(coupled, heavy)
    r = heavy_scene.rod
    f_beam = timoshenko_cantilever(r.bending_stiffness, r.shear_stiffness, r.mass_per_length, r.rotary_inertia, L,
                                   count=1)[0]
    return coupled, heavy, f_beam


def shock_tube_fields(sim):
    """(labels s, density, pressure, velocity) of a straight tube's fluid, from the simulation's state."""
    m, st = sim.model, sim.state
    t = m.tube
    cfg = t.config(np.concatenate([st.q[m.tube_q], st.lam[m.tube_lam]]))
    rho, p, u = t.fluid_fields(cfg, st.p[m.tube_p])
    return cfg.s, rho, p, u


def run_to_end(d, check=None):
    """The Simulation of scene dict ``d`` run to its time.end; ``check(sim, state before the step)`` after each step."""
    sim = Simulation(make(d)[1])
    n = int(round(d["time"]["end"] / d["time"]["step"]))
    for _ in range(n):
        before = sim.state.copy()
        sim.step()
        if check is not None:
            check(sim, before)
    return sim
