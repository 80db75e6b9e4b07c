"""Every example keeps the invariants its model declares (`varint check` lists them).

The declarations come from the terms (what each keeps or breaks) and the ends; this test runs each
example scene and checks every declared invariant with the monitor that measures it.  An invariant
name without a check here fails the test, so a new declaration cannot go unchecked, and a term that
declares a symmetry it does not keep is caught on the examples that use it.
"""

from pathlib import Path

import pytest

import varint
from helpers import invariant_error as _check

EXAMPLES = sorted((Path(__file__).resolve().parent.parent / "examples").glob("*.toml"))
STEPS = 30


def _run(path):
    model = varint.build_model(varint.load_scene(path))
    sim = varint.make_simulation(model)
    declared = model.describe()["invariants"]
    mons, fields = [sim.monitors()], [sim.fields()]
    for _ in range(STEPS):
        sim.step()
        mons.append(sim.monitors())
        fields.append(sim.fields())
    return model, declared, mons, fields


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.stem)
def test_examples_keep_their_declared_invariants(path):
    model, declared, mons, fields = _run(path)
    assert declared, f"{path.name}: no invariant declared"
    failures = []
    for name in declared:
        err, tol = _check(name, model, mons, fields)
        if not err <= tol:
            failures.append(f"{name}: {err:.3g} > {tol:g}")
    assert not failures, f"{path.name}: " + "; ".join(failures)


def test_a_false_declaration_is_caught():
    """The check is not vacuous: declaring linear momentum on a rod whose tip is loaded (momentum grows
    by the load's impulse every step) makes it fail."""
    path = next(p for p in EXAMPLES if p.stem == "cantilever_rod")
    model, _, mons, fields = _run(path)
    err, tol = _check("linear_momentum", model, mons, fields)
    assert err > 1e3 * tol
    with pytest.raises(AssertionError, match="no check"):
        _check("vorticity", model, mons, fields)
