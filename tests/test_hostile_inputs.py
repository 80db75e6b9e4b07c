"""A corpus of hostile inputs, scenes and command lines (issue 24: "What a new user hit in 0.2").

Each case must end with exit status 2 and exactly one line ``varint: error: ...`` on stderr that names the key or
the path at fault, without a traceback (the command runs in this process: anything but a VarintError escaping
``main`` fails the test), and must leave every file in its folder as it was (the files are hashed before and after,
and no file may appear or vanish).  The scene cases run through ``varint run`` (so that a refused scene writes no
run file) unless they say otherwise.
"""

from __future__ import annotations

import copy
import hashlib
import os
import shutil
from pathlib import Path

import pytest

from varint.cli import main
from varint.errors import SolverError
from varint.scene.standard import COUPLED_SECTION, LIQUID, gas_scene
from varint.scene.text import to_toml

from helpers import read_only_dir

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


# -- scenes -------------------------------------------------------------------------------------------------------


def _gas():
    d = gas_scene(nodes=9, parcels=8, end=2e-4)
    d["output"] = {"every": 5}
    return d


def _rod():
    return {"title": "rod", "tube": {"length": 1.0, "nodes": 6, "radius": 0.01},
            "rod": {"mass_per_length": 0.3, "rotary_inertia": 1e-4, "bending_stiffness": 2.0, "torsional_stiffness": 1.5,
                    "axial_stiffness": 1e3, "shear_stiffness": 8e2, "ends": {"s0": "clamped", "sL": "free"}},
            "time": {"step": 1e-3, "end": 2e-3}}


def _liquid_on_rod():
    """A rigid closed tube full of water on a clamped rod (the water hose without its wall)."""
    return {"title": "liquid on a rod", "tube": {"length": 1.0, "nodes": 6, "radius": 0.02},
            "rod": dict(COUPLED_SECTION, dimension=2, ends={"s0": "clamped", "sL": "free"}),
            "fluid": dict(LIQUID, parcels=10), "environment": {"gravity": [0.0, -9.81, 0.0]},
            "time": {"step": 1e-3, "end": 2e-3}}


def _set(d, path, value):
    """``d`` with the dotted ``path`` set (``fluid.perturbation`` lists are given whole)."""
    d = copy.deepcopy(d)
    *head, leaf = path.split(".")
    t = d
    for h in head:
        t = t.setdefault(h, {})
    if value is _DEL:
        del t[leaf]
    else:
        t[leaf] = value
    return d


_DEL = object()


def _edits(base, *pairs):
    d = base()
    for path, value in pairs:
        d = _set(d, path, value)
    return to_toml(d)


def _raw(text):
    return lambda: text


def _text(base, *pairs):
    return lambda: _edits(base, *pairs)


def _gas_text(old, new):
    def make():
        t = to_toml(_gas())
        assert old in t, old
        return t.replace(old, new, 1)
    return make


GAUSS = {"field": "pressure", "shape": "gaussian", "amplitude": 100.0, "center": 0.5, "width": 0.1}

#: (id, scene text maker, what the one line must name, command)
SCENES = [
    # what the TOML reader or Python itself could not take
    ("nested-2000-inline-tables", _raw('title = "x"\nfoo = ' + "{a=" * 2000 + "1" + "}" * 2000 + "\n"), "nest", "run"),
    ("nested-3000-arrays", _raw('title = "x"\nfoo = ' + "[" * 3000 + "]" * 3000 + "\n"), "nest", "check"),
    ("integer-of-5000-digits", _gas_text("nodes = 9", "nodes = " + "9" * 5000), "scene.toml", "run"),
    ("toml-syntax-error", _raw("title = 'x'\n[tube\nlength = 1\n"), "TOML syntax error", "run"),
    ("empty-file", _raw(""), "tube", "run"),
    # control characters in strings, which h5py or a terminal cannot take
    ("title-with-nul", _gas_text('title = "test scene"', 'title = "a\\u0000b"'), "title", "run"),
    ("title-with-escape", _gas_text('title = "test scene"', 'title = "red \\u001b[31m"'), "title", "run"),
    ("title-with-newline", _gas_text('title = "test scene"', 'title = "two\\nlines"'), "title", "check"),
    ("title-with-del", _gas_text('title = "test scene"', 'title = "a\\u007fb"'), "title", "run"),
    ("output-file-with-nul", _text(_gas, ("output.file", "out\u0000.h5")), "output.file", "run"),
    ("output-fields-with-bell", _text(_gas, ("output.fields", ["fl\u0007uid"])), "output.fields", "run"),
    ("choice-with-nul", _text(_gas, ("fluid.model", "ideal-gas\u0000")), "fluid.model", "check"),
    ("key-name-with-newline", _gas_text('title = "test scene"', 'title = "test scene"\n"a\\nb" = 1'), "unknown key", "run"),
    # sizes
    ("nodes-1e9", _gas_text("nodes = 9", "nodes = 1e9"), "tube.nodes", "run"),
    ("nodes-1e7", _gas_text("nodes = 9", "nodes = 10000000"), "tube.nodes", "run"),
    ("nodes-38-digits", _gas_text("nodes = 9", "nodes = 12345678901234567890123456789012345678"), "tube.nodes", "run"),
    ("length-400-digits", _gas_text("length = 1.0", "length = 1" + "0" * 400), "tube.length", "run"),
    ("parcels-38-digits", _gas_text("parcels = 8", "parcels = 12345678901234567890123456789012345678"), "fluid.parcels", "run"),
    ("rod-nodes-1e7", _text(_rod, ("tube.nodes", 10_000_000)), "tube.nodes", "run"),
    ("steps-1e600", _text(_gas, ("time.step", 1e-300), ("time.end", 1e300)), "time.end", "run"),
    ("end-1e9", _text(_gas, ("time.end", 1e9)), "time.end", "run"),
    # numbers whose derived quantities are not finite
    ("density-1e300", _text(_gas, ("fluid.density", 1e300)), "fluid.density", "run"),
    ("density-1e-300", _text(_gas, ("fluid.density", 1e-300)), "fluid.density", "check"),
    ("region-density-1e300", _text(_gas, ("fluid.initial", [{"from": 0.5, "to": 1.0, "density": 1e300, "pressure": 1e5}])),
     "fluid.initial[0].density", "run"),
    # nonsense that used to run silently
    ("gaussian-centre-outside", _text(_gas, ("fluid.perturbation", [dict(GAUSS, center=5.0)])), "fluid.perturbation[0].center", "run"),
    ("gaussian-centre-negative", _text(_gas, ("wall.perturbation", [dict(GAUSS, field="R", amplitude=1e-4, center=-0.2)])),
     "wall.perturbation[0].center", "run"),
    ("step-outside", _text(_gas, ("fluid.perturbation", [{"field": "pressure", "shape": "step", "amplitude": 10.0, "from": 2.0, "to": 3.0}])),
     "fluid.perturbation[0]", "run"),
    ("rod-perturbation-outside", _text(_rod, ("rod.perturbation", [{"field": "velocity", "shape": "gaussian", "amplitude": 0.1, "center": 1.5, "width": 0.1}])),
     "rod.perturbation[0].center", "run"),
    ("gravity-across-a-straight-tube", _text(_gas, ("environment.gravity", [0.0, -9.81, 0.0])), "environment.gravity", "run"),
    ("gravity-without-fluid", _text(_gas, ("fluid", _DEL), ("environment.gravity", [9.81, 0.0, 0.0])), "environment.gravity", "check"),
    ("closed-liquid-column-flowing", _text(_liquid_on_rod, ("fluid.velocity", 5.0)), "fluid.velocity", "run"),
    ("closed-liquid-region-flowing", _text(_liquid_on_rod, ("fluid.initial", [{"from": 0.0, "to": 0.5, "velocity": 1.0}])),
     "fluid.initial[0].velocity", "run"),
    # what validation always caught (kept so that it stays caught)
    ("unknown-key", _text(_gas, ("tube.lenght", 1.0)), "tube.lenght", "run"),
    ("unknown-section", _text(_gas, ("flud", {"model": "x"})), "flud", "run"),
    ("missing-tube", _text(_gas, ("tube", _DEL)), "tube", "run"),
    ("negative-length", _text(_gas, ("tube.length", -1.0)), "tube.length", "run"),
    ("string-length", _text(_gas, ("tube.length", "1")), "tube.length", "run"),
    ("nan-length", _gas_text("length = 1.0", "length = nan"), "tube.length", "run"),
    ("inf-radius", _gas_text("radius = 0.05", "radius = inf"), "tube.radius", "run"),
    ("two-nodes", _text(_gas, ("tube.nodes", 2)), "tube.nodes", "run"),
    ("fractional-nodes", _text(_gas, ("tube.nodes", 9.5)), "tube.nodes", "run"),
    ("unknown-fluid-model", _text(_gas, ("fluid.model", "gaz")), "fluid.model", "run"),
    ("gamma-below-one", _text(_gas, ("fluid.gamma", 0.9)), "fluid.gamma", "run"),
    ("one-parcel", _text(_gas, ("fluid.parcels", 1)), "fluid.parcels", "run"),
    ("parcels-3e6", _text(_gas, ("fluid.parcels", 3_000_000)), "fluid.parcels", "run"),
    ("zero-step", _text(_gas, ("time.step", 0.0)), "time.step", "run"),
    ("end-before-step", _text(_gas, ("time.end", 1e-6)), "time.end", "run"),
    ("unknown-scheme", _text(_gas, ("time.scheme", "rk4")), "time.scheme", "run"),
    ("poisson-0.7", _text(_gas, ("wall.poisson_ratio", 0.7)), "wall.poisson_ratio", "run"),
    ("negative-gas-pressure", _text(_gas, ("fluid.pressure", -1.0)), "fluid.pressure", "run"),
    ("gravity-of-two", _text(_gas, ("environment.gravity", [0.0, 0.0])), "environment.gravity", "run"),
    ("every-0", _text(_gas, ("output.every", 0)), "output.every", "run"),
    ("fields-of-a-rod-on-gas", _text(_gas, ("output.fields", ["rod"])), "output.fields", "run"),
    ("empty-output-file", _text(_gas, ("output.file", " ")), "output.file", "run"),
    ("region-reversed", _text(_gas, ("fluid.initial", [{"from": 0.8, "to": 0.2, "pressure": 1e5}])), "fluid.initial[0]", "run"),
    ("fluid-not-a-table", _text(_gas, ("fluid", 3)), "fluid", "run"),
    ("title-a-number", _text(_gas, ("title", 3)), "title", "run"),
    ("area-table-with-wall", _text(_gas, ("tube.area_table", [[0.0, 0.01], [1.0, 0.01]])), "tube.area_table", "run"),
    ("rod-without-material", _text(_rod, ("rod.mass_per_length", _DEL)), "rod.mass_per_length", "run"),
    ("rod-dimension-4", _text(_rod, ("rod.dimension", 4)), "rod.dimension", "run"),
    ("half-periodic", _text(_gas, ("fluid.ends", {"s0": "periodic", "sL": "closed"})), "fluid.ends", "run"),
    ("shock-capturing-a-liquid", _text(_liquid_on_rod, ("shock_capturing", {})), "shock_capturing", "run"),
    ("negative-density-bump", _text(_gas, ("fluid.perturbation", [dict(GAUSS, field="density", amplitude=-10.0)])),
     "fluid.perturbation", "run"),
    ("zero-direction", _text(_rod, ("rod.perturbation", [{"field": "velocity", "shape": "cosine", "wavelength": 1.0, "amplitude": 0.1,
                                                           "direction": [0.0, 0.0, 0.0]}])), "rod.perturbation[0].direction", "run"),
    ("modes-of-nul-title", _gas_text('title = "test scene"', 'title = "a\\u0000b"'), "title", "modes"),
    ("static-of-nodes-1e9", _text(_rod, ("tube.nodes", 1e9)), "tube.nodes", "static"),
    ("shock-of-density-1e300", _text(_gas, ("fluid.density", 1e300)), "fluid.density", "shock"),
]


def _argv(command, scene, tmp):
    if command == "run":
        return ["run", str(scene), "-o", str(tmp / "out.h5"), "-q"]
    if command == "static":
        return ["static", str(scene), "-o", str(tmp / "s.h5")]
    if command == "shock":
        return ["shock", str(scene), "--speed", "400"]
    return [command, str(scene)]


# -- files the command lines need ----------------------------------------------------------------------------------


def _hashes(root):
    out = {}
    for dirpath, dirnames, filenames in os.walk(root):
        for name in dirnames + filenames:
            p = Path(dirpath) / name
            if p.is_file():
                out[str(p)] = hashlib.sha256(p.read_bytes()).hexdigest()
            else:
                out[str(p)] = "dir"
    return out


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A finished run, a static file and a failed run of small scenes (made once; each test copies what it needs)."""
    import varint.run.simulation as simulation

    d = tmp_path_factory.mktemp("files")
    gas = d / "gas.toml"
    gas.write_text(to_toml(_gas()))
    assert main(["run", str(gas), "-o", str(d / "gas.h5"), "-q"]) == 0
    rod = d / "rod.toml"
    rod.write_text(to_toml(_rod()))
    assert main(["static", str(rod), "-o", str(d / "rod_static.h5")]) == 0
    real = simulation.Simulation.step

    def failing(self):
        if self.state.n == 12:
            raise SolverError(f"step {self.state.n} (t = {self.state.t:.6g} s): Newton did not converge (a test's failure)")
        return real(self)

    simulation.Simulation.step = failing
    try:
        assert main(["run", str(gas), "-o", str(d / "gas_failed.h5"), "-q"]) == 2
    finally:
        simulation.Simulation.step = real
    return d


def _copy(files, tmp, *names):
    for n in names:
        shutil.copy(files / n, tmp / n)


# each maker gets (tmp folder, the module's files) and returns (argv, what the line must name), or None to skip
def _cl_run_missing_scene(tmp, files):
    return ["run", str(tmp / "nope.toml"), "-q"], str(tmp / "nope.toml")


def _cl_run_scene_is_dir(tmp, files):
    (tmp / "d.toml").mkdir()
    return ["run", str(tmp / "d.toml"), "-o", str(tmp / "o.h5"), "-q"], str(tmp / "d.toml")


def _cl_run_existing_output(tmp, files):
    _copy(files, tmp, "gas.toml")
    (tmp / "precious.h5").write_bytes(b"data")
    return ["run", str(tmp / "gas.toml"), "-o", str(tmp / "precious.h5"), "-q"], str(tmp / "precious.h5")


def _cl_run_into_the_scene(tmp, files):
    _copy(files, tmp, "gas.toml")
    return ["run", str(tmp / "gas.toml"), "-o", str(tmp / "gas.toml"), "-q", "--force"], str(tmp / "gas.toml")


def _cl_run_into_a_dir(tmp, files):
    _copy(files, tmp, "gas.toml")
    (tmp / "out").mkdir()
    return ["run", str(tmp / "gas.toml"), "-o", str(tmp / "out"), "-q"], str(tmp / "out")


def _cl_run_into_a_missing_dir(tmp, files):
    _copy(files, tmp, "gas.toml")
    return ["run", str(tmp / "gas.toml"), "-o", str(tmp / "no" / "o.h5"), "-q"], str(tmp / "no" / "o.h5")


def _cl_run_under_a_file(tmp, files):
    _copy(files, tmp, "gas.toml")
    (tmp / "plain").write_text("x")
    return ["run", str(tmp / "gas.toml"), "-o", str(tmp / "plain" / "o.h5"), "-q"], str(tmp / "plain" / "o.h5")


def _cl_resume_missing(tmp, files):
    _copy(files, tmp, "gas.toml")
    return ["run", str(tmp / "gas.toml"), "-o", str(tmp / "none.h5"), "-q", "--resume"], str(tmp / "none.h5")


def _cl_resume_other_scene(tmp, files):
    _copy(files, tmp, "gas.h5")
    (tmp / "other.toml").write_text(to_toml(_set(_gas(), "time.end", 3e-4)))
    return ["run", str(tmp / "other.toml"), "-o", str(tmp / "gas.h5"), "-q", "--resume"], str(tmp / "gas.h5")


def _cl_resume_static(tmp, files):
    _copy(files, tmp, "rod.toml", "rod_static.h5")
    return ["run", str(tmp / "rod.toml"), "-o", str(tmp / "rod_static.h5"), "-q", "--resume"], str(tmp / "rod_static.h5")


def _cl_resume_text(tmp, files):
    _copy(files, tmp, "gas.toml")
    (tmp / "notes.h5").write_text("not hdf5")
    return ["run", str(tmp / "gas.toml"), "-o", str(tmp / "notes.h5"), "-q", "--resume"], str(tmp / "notes.h5")


def _cl_resume_failed(tmp, files):
    _copy(files, tmp, "gas.toml", "gas_failed.h5")
    return ["run", str(tmp / "gas.toml"), "-o", str(tmp / "gas_failed.h5"), "-q", "--resume"], str(tmp / "gas_failed.h5")


def _cl_run_into_read_only(tmp, files):
    _copy(files, tmp, "gas.toml")
    return ["run", str(tmp / "gas.toml"), "-o", str(tmp / "ro" / "o.h5"), "-q"], str(tmp / "ro" / "o.h5")


def _cl_static_into_read_only(tmp, files):
    _copy(files, tmp, "rod.toml")
    return ["static", str(tmp / "rod.toml"), "-o", str(tmp / "ro" / "s.h5")], str(tmp / "ro" / "s.h5")


def _cl_static_of_gas(tmp, files):
    """A rigid straight tube of gas has no static problem to solve (varint static: a [rod], or a [wall])."""
    d = _gas()
    d.pop("wall")
    (tmp / "rigid_gas.toml").write_text(to_toml(d))
    return ["static", str(tmp / "rigid_gas.toml"), "-o", str(tmp / "s.h5")], str(tmp / "rigid_gas.toml")


def _cl_static_existing(tmp, files):
    _copy(files, tmp, "rod.toml")
    (tmp / "s.h5").write_bytes(b"keep")
    return ["static", str(tmp / "rod.toml"), "-o", str(tmp / "s.h5")], str(tmp / "s.h5")


def _cl_info_text(tmp, files):
    (tmp / "notes.h5").write_text("not hdf5")
    return ["info", str(tmp / "notes.h5")], str(tmp / "notes.h5")


def _cl_info_missing(tmp, files):
    return ["info", str(tmp / "none.h5")], str(tmp / "none.h5")


def _cl_info_dir(tmp, files):
    (tmp / "d.h5").mkdir()
    return ["info", str(tmp / "d.h5")], str(tmp / "d.h5")


def _cl_info_empty_hdf5(tmp, files):
    import h5py

    with h5py.File(tmp / "empty.h5", "w"):
        pass
    return ["info", str(tmp / "empty.h5")], str(tmp / "empty.h5")


def _cl_plot_into_read_only(tmp, files):
    _copy(files, tmp, "gas.h5")
    return ["plot", str(tmp / "gas.h5"), "-d", str(tmp / "ro")], str(tmp / "ro")


def _cl_plot_into_a_file(tmp, files):
    _copy(files, tmp, "gas.h5")
    (tmp / "existing").write_text("mine")
    return ["plot", str(tmp / "gas.h5"), "-d", str(tmp / "existing")], str(tmp / "existing")


def _cl_plot_under_a_file(tmp, files):
    _copy(files, tmp, "gas.h5")
    (tmp / "existing").write_text("mine")
    return ["plot", str(tmp / "gas.h5"), "-d", str(tmp / "existing" / "pics")], str(tmp / "existing" / "pics")


def _cl_plot_text(tmp, files):
    (tmp / "notes.h5").write_text("not hdf5")
    return ["plot", str(tmp / "notes.h5"), "-d", str(tmp)], str(tmp / "notes.h5")


def _cl_sweep_into_read_only(tmp, files):
    _copy(files, tmp, "gas.toml")
    return (["sweep", str(tmp / "gas.toml"), "--vary", "fluid.velocity=0,1", "--analysis", "modes", "--out",
             str(tmp / "ro" / "x")], str(tmp / "ro" / "x"))


def _cl_sweep_into_a_file(tmp, files):
    _copy(files, tmp, "gas.toml")
    (tmp / "existing").write_text("mine")
    return (["sweep", str(tmp / "gas.toml"), "--vary", "fluid.velocity=0,1", "--analysis", "modes", "--out",
             str(tmp / "existing")], str(tmp / "existing"))


def _cl_sweep_unknown_key(tmp, files):
    _copy(files, tmp, "gas.toml")
    return (["sweep", str(tmp / "gas.toml"), "--vary", "fluid.velocty=0,1", "--analysis", "modes", "--out",
             str(tmp / "sw")], "fluid.velocty")


def _cl_sweep_bad_values(tmp, files):
    _copy(files, tmp, "gas.toml")
    return (["sweep", str(tmp / "gas.toml"), "--vary", "fluid.velocity=a:b:c", "--analysis", "modes", "--out",
             str(tmp / "sw")], "fluid.velocity")


def _cl_modes_count(tmp, files):
    _copy(files, tmp, "gas.toml")
    return ["modes", str(tmp / "gas.toml"), "-n", "0"], "-n/--count"


def _cl_shock_of_a_rod(tmp, files):
    _copy(files, tmp, "rod.toml")
    return ["shock", str(tmp / "rod.toml"), "--speed", "400"], str(tmp / "rod.toml")


COMMAND_LINES = {name[4:]: f for name, f in list(globals().items()) if name.startswith("_cl_")}


def _one_line(capsys):
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("varint: error: "), err[-3000:]
    assert "Traceback" not in err
    return lines[0]


def _check(argv, tmp, name, capsys):
    before = _hashes(tmp)
    assert main(argv) == 2
    line = _one_line(capsys)
    assert name in line, line
    assert _hashes(tmp) == before


@pytest.fixture
def read_only(tmp_path):
    undo = read_only_dir(tmp_path / "ro")
    yield undo
    if undo is not None:
        undo()


def test_the_corpus_is_large_enough():
    assert len(SCENES) + len(COMMAND_LINES) >= 60
    assert len({c[0] for c in SCENES}) == len(SCENES)


@pytest.mark.parametrize("case", SCENES, ids=[c[0] for c in SCENES])
def test_a_hostile_scene_is_one_line(tmp_path, capsys, case):
    _, make, name, command = case
    scene = tmp_path / "scene.toml"
    scene.write_text(make(), encoding="utf-8")
    _check(_argv(command, scene, tmp_path), tmp_path, name, capsys)


@pytest.mark.parametrize("case", sorted(COMMAND_LINES))
def test_a_hostile_command_line_is_one_line(tmp_path, capsys, files, read_only, case):
    if "read_only" in case and read_only is None:
        pytest.skip("no read-only folder can be made here")
    argv, name = COMMAND_LINES[case](tmp_path, files)
    _check(argv, tmp_path, name, capsys)
