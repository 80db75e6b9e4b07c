"""Helpers the tests share (the standard scenes themselves are varint.scene.standard's)."""

import numpy as np

from varint import build_model, parse_scene
from varint.analysis.signals import zero_crossing_frequency
from varint.scene.text import to_toml


def make(d):
    """Scene dict -> (scene, model)."""
    scene = parse_scene(to_toml(d))
    return scene, build_model(scene)


def tip_frequency(model, steps, scheme=None):
    """Angular frequency of a rod's tip motion in y over ``steps`` steps, from its zero crossings."""
    from varint import Simulation

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
