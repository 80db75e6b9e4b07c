"""The residual Newton drives to zero is the gradient of the discrete action (DESIGN §3).

For a short random lattice trajectory q_0, q_1, q_2 (and half-level algebraic
unknowns lam_{1/2}, lam_{3/2}) the action S = L_d(q_0, q_1, lam_{1/2}) + L_d(q_1, q_2, lam_{3/2})
is differentiated by central finite differences with respect to the interior
unknowns q_1 and lam_{3/2}; the step residual at level 1 must equal it.
The Jacobian Newton uses is checked against finite differences of the residual.
"""

import itertools

import numpy as np
import pytest

from varint.stepper import make_scheme

from helpers import AIR, gas_scene, make

WALLS = {
    "rigid": None,
    "rigid-table": "table",
    "dynamic-linear": {"model": "dynamic", "law": "linear", "a": 0.5, "beta1": 400.0, "beta2": 8e5},
    "dynamic-tubelaw": {"model": "dynamic", "law": "tube-law", "a": 0.5, "stiffness": 1e5, "tension": 0.3},
    "quasistatic-linear": {"model": "quasistatic", "law": "linear", "beta1": 400.0, "beta2": 8e5},
    "quasistatic-tubelaw": {"model": "quasistatic", "law": "tube-law", "stiffness": 1e5, "tension": 0.3},
}
FLUIDS = {
    "ideal-gas": dict(AIR),
    "barotropic": {"model": "barotropic", "density": 1000.0, "pressure": 1e5, "bulk_modulus": 2e6, "gamma": 7.15},
    "incompressible": {"model": "incompressible", "density": 1000.0, "pressure": 1e5},
    "none": None,
}


def _scene(wall, fluid, ends, scheme, gravity):
    d = gas_scene(nodes=9, parcels=7, ends=ends, scheme=scheme, h=1e-4)
    if fluid is None:
        del d["fluid"]
    else:
        d["fluid"] = dict(fluid, parcels=7, ends={"s0": ends, "sL": ends})
    if wall is None:
        d.pop("wall", None)
    elif wall == "table":
        d.pop("wall", None)
        d["tube"]["area_table"] = [[0.0, 0.006], [0.5, 0.009], [1.0, 0.007]]
    else:
        d["wall"] = dict(wall, perturbation=[{"field": "R", "shape": "cosine", "amplitude": 0.002, "wavelength": 1.0}])
    d["environment"] = {"external_pressure": 9.5e4, "gravity": [gravity, 0.0, 0.0]}
    return d


def _combos():
    for (wn, w), (fn, f), ends, scheme in itertools.product(WALLS.items(), FLUIDS.items(), ["closed", "periodic"],
                                                            ["midpoint", "trapezoidal"]):
        if f is None and (w is None or w == "table" or ends == "periodic"):
            continue  # nothing moves, or periodicity is a property of the fluid's ends
        if fn == "incompressible" and (w is None or w == "table"):
            continue  # refused by the scene validator
        if w == "table" and ends == "periodic":
            continue
        algebraic = fn == "incompressible" or (isinstance(w, dict) and w["model"] == "quasistatic")
        if scheme == "trapezoidal" and algebraic:
            continue  # refused by the scene validator (tested in test_scene)
        yield pytest.param(w, f, ends, scheme, id=f"{wn}-{fn}-{ends}-{scheme}")


def _scales(model):
    sc = np.ones(model.nz)
    for name, sl in model.layout.items():
        sc[sl] = {"s": model.L / max(model.M, 1), "R": model.R0, "mu": 1e4}[name]
    return sc


@pytest.mark.parametrize("wall,fluid,ends,scheme", list(_combos()))
def test_residual_is_gradient_of_discrete_action(wall, fluid, ends, scheme):
    scene, model = make(_scene(wall, fluid, ends, scheme, gravity=3.0 if fluid is not None else 0.0))
    S = make_scheme(model, 1e-4, scheme)
    rng = np.random.default_rng(42)
    nq, nl = model.nq, model.nlam
    scale = _scales(model)
    z0 = np.concatenate([model.q_init, model.lam_init])
    q = [z0[:nq] + 0.05 * scale[:nq] * rng.standard_normal(nq) for _ in range(3)]
    lam = [z0[nq:] + 0.05 * scale[nq:] * rng.standard_normal(nl) for _ in range(2)]

    def action(q1, lam1):
        return S.discrete_lagrangian(q[0], q1, lam[0]) + S.discrete_lagrangian(q1, q[2], lam1)

    p1 = S.momentum_plus(q[0], np.concatenate([q[1], lam[0]]))
    r = S.residual(q[1], p1, np.concatenate([q[2], lam[1]]))
    fd = np.empty(nq + nl)
    for i in range(nq + nl):
        e = 1e-4 * scale[i]
        if i < nq:
            dq = np.zeros(nq)
            dq[i] = e
            fd[i] = (action(q[1] + dq, lam[1]) - action(q[1] - dq, lam[1])) / (2 * e)
        else:
            dl = np.zeros(nl)
            dl[i - nq] = e
            fd[i] = (action(q[1], lam[1] + dl) - action(q[1], lam[1] - dl)) / (2 * e)
    # compare block by block: the blocks have different units
    for name, sl in model.layout.items():
        ref = np.abs(fd[sl]).max()
        assert np.allclose(r[sl], fd[sl], atol=2e-6 * ref, rtol=0), name


@pytest.mark.parametrize("wall,fluid,ends,scheme", [p for p in _combos() if "midpoint" in p.id and "closed" in p.id])
def test_jacobian_is_derivative_of_residual(wall, fluid, ends, scheme):
    scene, model = make(_scene(wall, fluid, ends, scheme, gravity=0.0))
    S = make_scheme(model, 1e-4, scheme)
    rng = np.random.default_rng(7)
    scale = _scales(model)
    z0 = np.concatenate([model.q_init, model.lam_init])
    qn = model.q_init + 0.05 * scale[:model.nq] * rng.standard_normal(model.nq)
    z = z0 + 0.05 * scale * rng.standard_normal(model.nz)
    pn = rng.standard_normal(model.nq) * 1e-3
    J = S.jacobian(qn, z).toarray()
    Jfd = np.empty_like(J)
    for i in range(model.nz):
        e = np.zeros(model.nz)
        e[i] = 1e-6 * scale[i]
        Jfd[:, i] = (S.residual(qn, pn, z + e) - S.residual(qn, pn, z - e)) / (2 * e[i])
    assert np.allclose(J, Jfd, atol=1e-6 * np.abs(J).max(), rtol=1e-5)
