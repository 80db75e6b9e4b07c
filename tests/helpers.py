"""Shared helpers: scenes written as Python dicts and emitted as TOML text."""

import copy
import math

import numpy as np


from varint import build_model, parse_scene


def _value(v):
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_value(x)}" for k, x in v.items()) + " }"
    if isinstance(v, float):
        return repr(v)
    return str(v)


def to_toml(d):
    """Emit a scene dict as TOML: top-level scalars, [tables], [[arrays of tables]] one level deep."""
    lines = [f"{k} = {_value(v)}" for k, v in d.items() if not isinstance(v, dict)]
    for sec, body in d.items():
        if not isinstance(body, dict):
            continue
        lines.append(f"\n[{sec}]")
        arrays = {}
        for k, v in body.items():
            if isinstance(v, list) and v and all(isinstance(x, dict) for x in v):
                arrays[k] = v
            else:
                lines.append(f"{k} = {_value(v)}")
        for k, items in arrays.items():
            for item in items:
                lines.append(f"\n[[{sec}.{k}]]")
                lines += [f"{kk} = {_value(vv)}" for kk, vv in item.items()]
    return "\n".join(lines) + "\n"


RUBBER_WALL = {"model": "dynamic", "law": "linear", "thickness": 1.0e-3, "density": 1522.0,
               "youngs_modulus": 5.0e6, "poisson_ratio": 0.5}
AIR = {"model": "ideal-gas", "gamma": 1.4, "density": 1.225, "pressure": 101325.0}


def gas_scene(nodes=33, parcels=32, length=1.0, wall=True, ends="closed", h=1e-5, end=1e-3,
              scheme="midpoint", perturbation=None, fluid_velocity=None, **extra):
    d = {"title": "test scene",
         "tube": {"length": length, "nodes": nodes, "radius": 0.05},
         "fluid": dict(AIR, parcels=parcels, ends={"s0": ends, "sL": ends}),
         "environment": {"external_pressure": 101325.0},
         "time": {"step": h, "end": end, "scheme": scheme}}
    if wall:
        d["wall"] = dict(RUBBER_WALL)
    if perturbation is not None:
        d["fluid"]["perturbation"] = perturbation
    for k, v in extra.items():
        d[k] = v
    return d


def make(d):
    """Scene dict -> (scene, model)."""
    scene = parse_scene(to_toml(d))
    return scene, build_model(scene)




def zero_crossing_frequency(t, y):
    """Angular frequency from the spacing of the first and last zero crossings of y(t) (linear interpolation).

    y must oscillate about zero (no mean is subtracted: over a non-integer number of periods
    the sample mean of a pure cosine is not zero and would bias the crossings).
    """
    idx = np.nonzero(np.sign(y[:-1]) * np.sign(y[1:]) < 0)[0]
    tc = t[idx] - y[idx] * (t[idx + 1] - t[idx]) / (y[idx + 1] - y[idx])
    return math.pi * (len(tc) - 1) / (tc[-1] - tc[0])


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
    after=0 and calls = the starts tried before varint.rod_em.halved_step, only those fail.  Attempts at other step
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
