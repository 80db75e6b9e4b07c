"""Scene validation: every bad input is one line naming the key and the problem, never a traceback."""

import copy
import subprocess
import sys
from pathlib import Path

import pytest

from varint.cli import main
from varint.scene.schema import load_scene

from varint.scene.standard import gas_scene
from varint.scene.text import to_toml

EXAMPLES = sorted(Path(__file__).parent.parent.joinpath("examples").glob("*.toml"))


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.name)
def test_examples_are_valid(path):
    assert load_scene(path).title


def _set(d, path, value):
    keys = path.split(".")
    for k in keys[:-1]:
        d = d.setdefault(k, {})
    if value is _DEL:
        del d[keys[-1]]
    else:
        d[keys[-1]] = value


_DEL = object()
PERT = {"field": "pressure", "shape": "cosine", "amplitude": 10.0, "wavelength": 1.0}

# (id, [(key path, value)], text expected in the one-line message)
BAD = [
    ("missing-title", [("title", _DEL)], "title: missing"),
    ("missing-tube", [("tube", _DEL)], "tube: missing section"),
    ("missing-length", [("tube.length", _DEL)], "tube.length: missing"),
    ("negative-length", [("tube.length", -1.0)], "tube.length: must be > 0"),
    ("zero-radius", [("tube.radius", 0.0)], "tube.radius: must be > 0"),
    ("nodes-float", [("tube.nodes", 10.5)], "tube.nodes: must be a whole number"),
    ("nodes-too-few", [("tube.nodes", 2)], "tube.nodes: must be >= 3"),
    ("length-string", [("tube.length", "one")], "tube.length: must be a number"),
    ("unknown-tube-key", [("tube.lenght", 1.0)], "tube.lenght: unknown key (did you mean 'length'?)"),
    ("unknown-section", [("fluids", {"a": 1})], "fluids: unknown key (did you mean 'fluid'?)"),
    ("rod-with-periodic-fluid", [("fluid.ends", {"s0": "periodic", "sL": "periodic"}), ("rod", {"mass_per_length": 1.0, "rotary_inertia": 1e-4, "bending_stiffness": 1.0, "torsional_stiffness": 1.0, "axial_stiffness": 1e3, "shear_stiffness": 1e3})], "fluid.ends: a [fluid] on a [rod] is periodic exactly when the rod is"),
    ("rod-with-wall-only", [("fluid", _DEL), ("rod", {"mass_per_length": 1.0, "rotary_inertia": 1e-4, "bending_stiffness": 1.0, "torsional_stiffness": 1.0, "axial_stiffness": 1e3, "shear_stiffness": 1e3})], "wall: a [wall] on a [rod] needs a [fluid]"),
    ("rod-liquid-hydraulic-lock", [("wall", _DEL), ("fluid", {"model": "incompressible", "density": 1000.0, "parcels": 8}), ("rod", {"mass_per_length": 1.0, "rotary_inertia": 1e-4, "bending_stiffness": 1.0, "torsional_stiffness": 1.0, "axial_stiffness": 1e3, "shear_stiffness": 1e3, "ends": {"s0": "pinned", "sL": "clamped"}})], "fluid.model: an incompressible liquid in a rigid, closed tube that is straight and held at both ends"),
    ("rod-perturbation-out-of-plane", [("wall", _DEL), ("fluid", _DEL), ("rod", {"dimension": 2, "youngs_modulus": 1e6, "thickness": 0.01, "density": 1e3, "perturbation": [{"field": "velocity", "shape": "cosine", "wavelength": 1.0, "amplitude": 0.1, "direction": [0.0, 0.0, 1.0]}]})], "rod.perturbation[0].direction: a planar rod"),
    ("rod-perturbation-field", [("wall", _DEL), ("fluid", _DEL), ("rod", {"youngs_modulus": 1e6, "thickness": 0.01, "density": 1e3, "perturbation": [{"field": "R", "shape": "cosine", "wavelength": 1.0, "amplitude": 0.1}]})], "rod.perturbation[0].field: unknown value 'R'"),
    ("rod-missing-density", [("wall", _DEL), ("fluid", _DEL), ("rod", {"youngs_modulus": 1e6, "thickness": 0.01})], "rod.density: missing"),
    ("rod-mixed-forms", [("wall", _DEL), ("fluid", _DEL), ("rod", {"youngs_modulus": 1e6, "thickness": 0.01, "density": 1e3, "bending_stiffness": 1.0})], "rod.youngs_modulus: give either the material form or the stiffness form"),
    ("rod-bad-end", [("wall", _DEL), ("fluid", _DEL), ("rod", {"youngs_modulus": 1e6, "thickness": 0.01, "density": 1e3, "ends": {"s0": "welded"}})], "rod.ends.s0: unknown value 'welded'"),
    ("rod-planar-out-of-plane", [("wall", _DEL), ("fluid", _DEL), ("rod", {"dimension": 2, "youngs_modulus": 1e6, "thickness": 0.01, "density": 1e3, "load": {"force": [0.0, 0.0, 1.0]}})], "rod.load.force: a planar rod"),
    ("rod-dimension-4", [("wall", _DEL), ("fluid", _DEL), ("rod", {"dimension": 4, "youngs_modulus": 1e6, "thickness": 0.01, "density": 1e3})], "rod.dimension: must be <= 3"),
    ("rod-unknown-initial-key", [("wall", _DEL), ("fluid", _DEL), ("rod", {"youngs_modulus": 1e6, "thickness": 0.01, "density": 1e3, "initial": {"spin": [0.0, 0.0, 1.0]}})], "rod.initial.spin: unknown key"),
    ("shock-with-quasistatic-wall", [("shock_capturing", {}), ("wall.model", "quasistatic")], "shock_capturing: needs wall.model = 'dynamic'"),
    ("unknown-fluid-model", [("fluid.model", "ideal_gas")], "fluid.model: unknown value 'ideal_gas'"),
    ("too-many-parcels", [("fluid.parcels", 3_000_000)], "fluid.parcels: must be <= 2000000, got 3000000"),
    ("gamma-below-one", [("fluid.gamma", 0.9)], "fluid.gamma: must be >= 1"),
    ("gamma-one-gas", [("fluid.gamma", 1.0)], "fluid.gamma: must be > 1 for an ideal gas"),
    ("negative-density", [("fluid.density", -1.0)], "fluid.density: must be > 0"),
    ("negative-pressure-gas", [("fluid.pressure", -5.0)], "fluid.pressure: must be > 0 for an ideal gas"),
    ("missing-parcels", [("fluid.parcels", _DEL)], "fluid.parcels: missing"),
    ("one-parcel", [("fluid.parcels", 1)], "fluid.parcels: must be >= 2"),
    ("one-periodic-end", [("fluid.ends", {"s0": "periodic", "sL": "closed"})], "fluid.ends: periodic must be set at both ends"),
    ("inflow-alone", [("fluid.ends", {"s0": "inflow", "sL": "closed"})], "fluid.ends: open ends come in a pair"),
    ("inlet-key-closed", [("fluid.ends", {"inflow_velocity": 1.0})], "fluid.ends.inflow_velocity: only for open ends"),
    ("inflow-not-flowing", [("fluid.ends", {"s0": "inflow", "sL": "outflow"})], "fluid.velocity: a velocity inlet needs fluid flowing in"),
    ("bad-end-name", [("fluid.ends", {"s0": "open", "sL": "closed"})], "fluid.ends.s0: unknown value 'open'"),
    ("barotropic-needs-bulk", [("fluid.model", "barotropic")], "fluid.bulk_modulus: missing"),
    ("bulk-on-gas", [("fluid.bulk_modulus", 1e9)], "fluid.bulk_modulus: not used"),
    ("incompressible-rigid", [("fluid", {"model": "incompressible", "density": 1000.0, "parcels": 8}), ("wall", _DEL)], "fluid.model: an incompressible fluid in a rigid straight tube"),
    ("bad-shape", [("fluid.perturbation", [dict(PERT, shape="square")])], "fluid.perturbation[0].shape: unknown value 'square'"),
    ("cosine-no-wavelength", [("fluid.perturbation", [{"field": "pressure", "shape": "cosine", "amplitude": 1.0}])], "fluid.perturbation[0].wavelength: missing"),
    ("gaussian-no-width", [("fluid.perturbation", [{"field": "density", "shape": "gaussian", "amplitude": 0.01, "center": 0.5}])], "fluid.perturbation[0].width: missing"),
    ("step-reversed", [("fluid.perturbation", [{"field": "velocity", "shape": "step", "amplitude": 1.0, "from": 0.6, "to": 0.2}])], "fluid.perturbation[0].to: must be > from"),
    ("bad-field", [("fluid.perturbation", [dict(PERT, field="temperature")])], "fluid.perturbation[0].field: unknown value 'temperature'"),
    ("wavelength-on-gaussian", [("fluid.perturbation", [{"field": "pressure", "shape": "gaussian", "amplitude": 1.0, "center": 0.5, "width": 0.1, "wavelength": 1.0}])], "fluid.perturbation[0].wavelength: not used by shape = 'gaussian'"),
    ("pressure-pert-too-big", [("fluid.perturbation", [dict(PERT, amplitude=-2e5)])], "fluid.perturbation: makes the pressure non-positive"),
    ("region-outside", [("fluid.initial", [{"from": 0.5, "to": 2.0, "pressure": 2e5}])], "fluid.initial[0]: needs 0 <= from < to <= 1"),
    ("wall-bad-model", [("wall.model", "elastic")], "wall.model: unknown value 'elastic'"),
    ("wall-no-inertia-data", [("wall.density", _DEL)], "wall.a: missing: give a, or thickness and density"),
    ("quasistatic-with-a", [("wall.model", "quasistatic"), ("wall.a", 0.3)], "wall.a: a quasistatic wall has no inertia"),
    ("poisson-too-big", [("wall.poisson_ratio", 0.7)], "wall.poisson_ratio: must be <= 0.5"),
    ("tube-law-with-beta", [("wall.law", "tube-law"), ("wall.beta2", 1e5)], "wall.beta2: belongs to law = 'linear'"),
    ("wall-pert-bad-field", [("wall.perturbation", [dict(PERT, field="pressure")])], "wall.perturbation[0].field: 'pressure' cannot be perturbed here"),
    ("wall-pert-negative-R", [("wall.perturbation", [{"field": "R", "shape": "cosine", "amplitude": 0.2, "wavelength": 1.0}])], "wall.perturbation: makes the radius non-positive"),
    ("area-table-with-wall", [("tube.area_table", [[0.0, 0.01], [1.0, 0.01]])], "tube.area_table: only for a rigid wall"),
    ("area-table-short", [("wall", _DEL), ("tube.area_table", [[0.0, 0.01], [0.5, 0.01]])], "tube.area_table: must cover the tube"),
    ("gravity-two-components", [("environment.gravity", [0.0, -9.81])], "environment.gravity: must be a list of 3 finite numbers"),
    ("missing-step", [("time.step", _DEL)], "time.step: missing"),
    ("end-before-step", [("time.end", 1e-6)], "time.end: must be >= time.step"),
    ("bad-scheme", [("time.scheme", "rk4")], "time.scheme: unknown value 'rk4'"),
    ("trapezoidal-incompressible", [("fluid", {"model": "incompressible", "density": 1000.0, "parcels": 8}), ("time.scheme", "trapezoidal")], "time.scheme: 'trapezoidal' needs every unknown to carry inertia"),
    ("newton-tol-zero", [("time.newton_tol", 0.0)], "time.newton_tol: must be > 0"),
    ("output-every-zero", [("output", {"every": 0})], "output.every: must be >= 1"),
    ("output-unknown-field", [("output", {"fields": ["rod"]})], "output.fields: unknown or absent field group 'rod'"),
    ("bool-as-number", [("tube.nodes", True)], "tube.nodes: must be a number"),
    ("no-effects", [("wall", _DEL), ("fluid", _DEL)], "(scene): no effects"),
]


@pytest.mark.parametrize("mutations,expected", [pytest.param(m, e, id=i) for i, m, e in BAD])
def test_bad_scene_is_one_line_naming_the_key(tmp_path, capsys, mutations, expected):
    d = copy.deepcopy(gas_scene())
    for path, value in mutations:
        _set(d, path, value)
    f = tmp_path / "scene.toml"
    f.write_text(to_toml(d))
    code = main(["check", str(f)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code != 0
    assert len(err) == 1, err
    assert expected in err[0], err[0]
    assert err[0].startswith("varint: error: ") and "Traceback" not in err[0]


def test_toml_syntax_error(tmp_path, capsys):
    f = tmp_path / "s.toml"
    f.write_text("title = 'x'\n[tube\nlength = 1\n")
    assert main(["check", str(f)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "TOML syntax error" in err[0] and "line 2" in err[0]


def test_missing_file(tmp_path, capsys):
    assert main(["run", str(tmp_path / "nope.toml")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nope.toml: no such file" in err[0]


def test_several_problems_give_one_line_each(tmp_path, capsys):
    d = gas_scene()
    d["tube"]["length"] = -1.0
    d["fluid"]["gamma"] = "big"
    f = tmp_path / "s.toml"
    f.write_text(to_toml(d))
    assert main(["check", str(f)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and any("tube.length" in e for e in err) and any("fluid.gamma" in e for e in err)


def test_cli_process_exit_code_and_no_traceback(tmp_path):
    f = tmp_path / "s.toml"
    f.write_text("title = 'x'\n[tube]\nlength = 1.0\nnodes = 5\nradius = 0.1\nspeed = 3\n[time]\nstep = 0.1\nend = 1.0\n")
    r = subprocess.run([sys.executable, "-m", "varint", "check", str(f)], capture_output=True, text=True)
    assert r.returncode == 2
    assert r.stderr.strip().count("\n") == 0 and "tube.speed: unknown key" in r.stderr and "Traceback" not in r.stderr


def test_check_reports_effects_unknowns_and_invariants(tmp_path, capsys):
    f = tmp_path / "s.toml"
    f.write_text(to_toml(gas_scene(nodes=17, parcels=16)))
    assert main(["check", str(f)]) == 0
    out = capsys.readouterr().out
    assert "effects: wall, fluid, external_pressure" in out
    assert "s (15), R (17)" in out
    assert "expected invariants: energy, mass, parcel_entropy" in out


@pytest.mark.parametrize("ends,words", [
    ({"s0": "closed", "sL": "closed"}, "closed ends"),
    ({"s0": "inflow", "sL": "outflow", "inflow_velocity": 3.0, "outflow_pressure": 9.0e4},
     "open ends (velocity inlet at 3 m/s; outlet at 90000 Pa)"),
    ({"s0": "inflow", "sL": "outflow", "inflow": "pressure", "inflow_pressure": 1.2e5},
     "open ends (pressure inlet at 120000 Pa; outlet at"),
])
def test_check_says_what_the_fluid_ends_are(tmp_path, capsys, ends, words):
    d = copy.deepcopy(gas_scene())
    d["fluid"]["ends"] = ends
    f = tmp_path / "scene.toml"
    f.write_text(to_toml(d))
    assert main(["check", str(f)]) == 0
    lattice = [line for line in capsys.readouterr().out.splitlines() if line.strip().startswith("lattice:")]
    assert len(lattice) == 1 and words in lattice[0], lattice


@pytest.mark.parametrize("parcels,hint", [(40, False), (20, True)])
def test_check_says_the_parcels_per_element_of_a_flowing_pipe_and_warns_below_two(tmp_path, capsys, parcels, hint):
    """A rod carrying liquid through open ends: the lattice line gives the parcels per element and, below two, points
    at the label-passing instability (docs/theory.md §12)."""
    from varint.scene.standard import pipe_scene_text

    f = tmp_path / "pipe.toml"
    f.write_text(pipe_scene_text(nodes=21, parcels=parcels, constraint="inextensible_unshearable"))
    assert main(["check", str(f)]) == 0
    out = capsys.readouterr().out.splitlines()
    lattice = [line for line in out if line.strip().startswith("lattice:")]
    assert len(lattice) == 1 and f"{parcels} parcels ({parcels / 20:g} per element), open ends" in lattice[0], lattice
    assert any(line.strip().startswith("rod: dimension = 2") for line in out)  # the rod's lines stay
    assert any(line.strip().startswith("initial shape:") for line in out)
    assert ("fewer than 2 parcels per element" in lattice[0]) == hint


# -- a Section reads its declared keys as attributes, and nothing else


def _sections(scene):
    """(schema name, Section) of every section of a scene that the schema declares, sub-tables and array entries
    included (the top level's one key, title, is the Scene's own attribute)."""
    from varint.scene.schema import SCHEMA

    out = []
    for name in SCHEMA:
        if not name:
            continue
        parts = name.rstrip("[]").split(".")
        node = getattr(scene, parts[0])
        for part in parts[1:]:
            node = None if node is None else getattr(node, part)
        if node is None:
            continue
        out += [(name, entry) for entry in node] if name.endswith("[]") else [(name, node)]
    return out


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.name)
def test_every_declared_key_of_every_section_reads_as_an_attribute(path):
    """Walk SCHEMA over each example: every key declared for a section the scene has reads without error (the
    validator fills each with its value or default, also in the entries it builds itself, e.g. the wall's
    perturbation of [initial.traveling_shock])."""
    from varint.scene.schema import SCHEMA

    scene = load_scene(path)
    found = _sections(scene)
    assert any(name == "time" for name, _ in found)
    for name, section in found:
        for key in SCHEMA[name]:
            assert getattr(section, key.name) == section[key.name], (path.name, name, key.name)


def test_a_misspelt_attribute_raises_naming_the_section_and_the_key():
    """scene.fluid.densty used to read None (a Section's attributes were dict.get); it names the key now."""
    scene = load_scene(EXAMPLES[0].parent / "rubber_tube_pulse.toml")
    with pytest.raises(AttributeError, match=r"^fluid\.densty: no such key in this section$"):
        scene.fluid.densty
    with pytest.raises(AttributeError, match=r"^fluid\.ends\.s1: no such key in this section$"):
        scene.fluid.ends.s1
    with pytest.raises(AttributeError, match=r"^fluid\.perturbation\[0\]\.amplitute: no such key"):
        scene.fluid.perturbation[0].amplitute
    with pytest.raises(AttributeError, match=r"^time\.stepp: no such key"):
        scene.time.stepp
    # a declared key left at its default (None) still reads; a key only some scenes carry reads by get or in
    assert scene.environment.external_pressure is not None and scene.output.file is None
    assert scene.fluid.get("traveling_shock") is None and "traveling_shock" not in scene.fluid
    assert getattr(scene.fluid, "traveling_shock", None) is None and not hasattr(scene.fluid, "traveling_shock")
    # the Section is still a dict, copies and pickles as one, and keeps its place in the scene
    import pickle

    for twin in (copy.deepcopy(scene.fluid), pickle.loads(pickle.dumps(scene.fluid))):
        assert twin == scene.fluid and twin.density == scene.fluid.density
        with pytest.raises(AttributeError, match=r"^fluid\.densty: "):
            twin.densty


def test_the_traveling_shock_example_carries_its_internal_entries():
    """[initial.traveling_shock] adds fluid.traveling_shock and replaces wall.perturbation: both read by attribute."""
    scene = load_scene(EXAMPLES[0].parent / "rubber_tube_traveling_shock.toml")
    assert scene.fluid.traveling_shock.position == scene.initial.traveling_shock.position
    (p,) = scene.wall.perturbation
    assert p.shape == "traveling_shock" and p.field == "R" and p.amplitude is None
    with pytest.raises(AttributeError, match=r"^fluid\.traveling_shock\.speed: no such key"):
        scene.fluid.traveling_shock.speed
