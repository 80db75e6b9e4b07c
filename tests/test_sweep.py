"""``varint sweep``: --vary specs, setting keys in the scene's TOML, validation before anything runs,
modes and run sweeps on a local Dask cluster (2 worker processes), failing points, re-runs."""

import csv
import math
import tomllib
from pathlib import Path

import pytest

from varint.exact.beams import spinning_shaft_whirl
from varint.cli import main
from varint.errors import SceneError, VarintError
from varint.analysis.modes import strongest
from varint.scene.schema import parse_scene
from varint.sweep import parse_vary, point_numbers, point_texts
from varint.scene.text import set_key, to_toml

from varint.scene.standard import gas_scene
from varint.scene.text import to_toml as dict_to_toml

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
SPIN_KEY = "rod.initial.angular_velocity[0]"


def _error_lines(capsys):
    cap = capsys.readouterr()
    return [ln for ln in cap.err.splitlines() if ln.strip()], cap.out


def _table(path):
    with open(path, newline="") as f:
        r = csv.DictReader(f)
        return r.fieldnames, list(r)


# -- --vary specs ------------------------------------------------------------------------------------


def test_vary_range_is_inclusive_and_typed_by_the_scene_key():
    v = parse_vary(f"{SPIN_KEY}=0:60:3")
    assert v.key == SPIN_KEY and v.values == [0.0, 30.0, 60.0] and all(type(x) is float for x in v.values)
    v = parse_vary("tube.nodes=11:21:3")  # an int key: ints
    assert v.values == [11, 16, 21] and all(type(x) is int for x in v.values)
    assert parse_vary("tube.nodes=11,13").values == [11, 13]
    assert parse_vary("time.step=1e-3, 2e-3").values == [1e-3, 2e-3]
    assert parse_vary("fluid.perturbation[1].amplitude=5").values == [5.0]
    assert parse_vary("rod.ends.s0=pinned,clamped").values == ["pinned", "clamped"]  # strings stay strings
    assert parse_vary("time.step=2e-3:2e-3:1").values == [2e-3]


@pytest.mark.parametrize("spec, words", [
    ("time.step", "expected KEY=START:STOP:NUM"),
    ("=1,2", "no key before '='"),
    ("time.step=", "no values"),
    ("time.stepp=1", "unknown scene key (did you mean 'time.step'?)"),
    ("rod.initial.angular_velocity=1,2", "is a vector; vary one component"),
    ("rod.initial.angular_velocity[3]=1", "components [0], [1], [2]"),
    ("time.step[0]=1", "not a vector"),
    ("fluid.perturbation.amplitude=1", "index it, e.g. fluid.perturbation[0].amplitude"),
    ("tube.area_table=1", "cannot be varied"),
    ("time.step=1:2", "a range is START:STOP:NUM"),
    ("time.step=0:1:0", "NUM must be >= 1"),
    ("time.step=0:1:x", "NUM must be a whole number"),
    ("time.step=a,b", "'a' is not a number"),
    ("time.step=1,,2", "empty value"),
    ("time.step=1,1", "repeated"),
    ("time.step=inf", "not a finite number"),
    ("tube.nodes=3.5", "is a whole number, got 3.5"),
    ("tube.nodes=11:21:4", "is a whole number, but 11:21:4 gives"),
    ("rod.ends.s0=a:b:2", "is a string"),
    ("rod..x=1", "not a dotted scene key"),
])
def test_vary_errors_name_the_option(spec, words):
    with pytest.raises(VarintError) as e:
        parse_vary(spec)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith("--vary ") and words in msg, msg


# -- setting keys in the TOML ------------------------------------------------------------------------


@pytest.mark.parametrize("example", sorted(p.name for p in EXAMPLES.glob("*.toml")))
def test_toml_writer_round_trips_every_example(example):
    """Inline tables (ends = {...}), arrays of tables, nested tables, pairs: tomllib reads back the same document."""
    doc = tomllib.loads((EXAMPLES / example).read_text())
    text = to_toml(doc)
    assert tomllib.loads(text) == doc
    parse_scene(text)


def test_set_key_in_nested_tables_arrays_of_tables_and_vectors():
    doc = tomllib.loads((EXAMPLES / "rubber_tube_pulse.toml").read_text())
    doc["fluid"]["perturbation"].append({"field": "velocity", "shape": "cosine", "amplitude": 1.0, "wavelength": 2.0})
    set_key(doc, parse_vary("fluid.perturbation[1].amplitude=3").path, 3.0)
    set_key(doc, parse_vary("fluid.ends.s0=periodic").path, "periodic")  # written inline in the file
    set_key(doc, parse_vary("environment.gravity[0]=-9.81").path, -9.81)  # absent vector: from its default
    set_key(doc, parse_vary("tube.nodes=101").path, 101)
    back = tomllib.loads(to_toml(doc))
    assert back["fluid"]["perturbation"][0]["amplitude"] == 5000.0 and back["fluid"]["perturbation"][1]["amplitude"] == 3.0
    assert back["fluid"]["ends"] == {"s0": "periodic", "sL": "closed"}
    assert back["environment"]["gravity"] == [-9.81, 0.0, 0.0] and back["environment"]["external_pressure"] == 101325.0
    assert back["tube"]["nodes"] == 101 and type(back["tube"]["nodes"]) is int
    doc = tomllib.loads((EXAMPLES / "spinning_shaft.toml").read_text())
    set_key(doc, parse_vary(f"{SPIN_KEY}=30").path, 30.0)
    assert tomllib.loads(to_toml(doc))["rod"]["initial"]["angular_velocity"] == [30.0, 0.0, 0.0]
    with pytest.raises(VarintError, match=r"fluid.perturbation\[2\]: the scene has 1 \[\[fluid.perturbation\]\] table$"):
        set_key(tomllib.loads((EXAMPLES / "rubber_tube_pulse.toml").read_text()), parse_vary("fluid.perturbation[2].width=1").path, 1.0)


def test_points_are_the_product_of_the_values_each_validated():
    text = (EXAMPLES / "spinning_shaft.toml").read_text()
    pts = point_texts(text, [parse_vary(f"{SPIN_KEY}=0,60"), parse_vary("tube.nodes=11,21")])
    assert [v for v, _ in pts] == [(0.0, 11), (0.0, 21), (60.0, 11), (60.0, 21)]
    sc = parse_scene(pts[3][1])
    assert sc.rod.initial.angular_velocity == (60.0, 0.0, 0.0) and sc.tube.nodes == 21
    with pytest.raises(SceneError) as e:
        point_texts(text, [parse_vary("tube.nodes=11,2")], source="shaft.toml")
    assert str(e.value) == "shaft.toml: sweep point 1 (tube.nodes = 2): tube.nodes: must be >= 3, got 2"


def test_point_numbers_are_places_in_the_product_unless_taken():
    idents = [("0",), ("1",), ("2",), ("3",)]
    assert point_numbers(idents, {}) == {("0",): 0, ("1",): 1, ("2",): 2, ("3",): 3}
    # an interrupted sweep that finished points 0 and 2 (out of order): the others keep their places
    assert point_numbers(idents, {("0",): "0", ("2",): "2"}) == {("1",): 1, ("3",): 3}
    # an extended sweep (a value inserted before the finished ones): numbers no kept row uses
    assert point_numbers([("-1",), ("0",), ("1",)], {("0",): "0", ("1",): "1"}) == {("-1",): 2}


def test_an_invalid_point_is_refused_before_anything_runs(tmp_path, capsys, monkeypatch):
    import varint.sweep

    def no_cluster(*a, **k):
        raise AssertionError("a cluster was started")

    monkeypatch.setattr(varint.sweep, "_client", no_cluster)
    out = tmp_path / "out"
    code = main(["sweep", str(EXAMPLES / "spinning_shaft.toml"), "--vary", f"{SPIN_KEY}=0,60",
                 "--vary", "rod.ends.s0=pinned,clampd", "--analysis", "modes", "--out", str(out)])
    err, stdout = _error_lines(capsys)
    assert code == 2 and stdout == "" and len(err) == 1, err
    assert err[0].startswith("varint: error: ") and "sweep point 1" in err[0] and "rod.ends.s0 = clampd" in err[0]
    assert "unknown value 'clampd'" in err[0]
    assert not out.exists()
    assert main(["sweep", str(EXAMPLES / "spinning_shaft.toml"), "--vary", "tube.nodez=3", "--analysis", "run",
                 "--out", str(out)]) == 2
    err, _ = _error_lines(capsys)
    assert err == ["varint: error: --vary tube.nodez: unknown scene key (did you mean 'tube.nodes'?)"]
    assert not out.exists()


def test_a_directory_of_another_sweep_is_refused(tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    (out / "sweep.json").write_text('{"scene": "other.toml", "scene_toml": "title = \\"x\\"", "analysis": "modes", "keys": []}')
    assert main(["sweep", str(EXAMPLES / "spinning_shaft.toml"), "--vary", f"{SPIN_KEY}=0", "--analysis", "modes",
                 "--out", str(out)]) == 2
    err, _ = _error_lines(capsys)
    assert len(err) == 1 and "holds a sweep with another scene" in err[0] and "other.toml" in err[0], err


def test_strongest_mode_summary():
    rigid = {"frequency": 0.0, "growth_rate": 0.0}
    res = [rigid, {"frequency": 3.0, "growth_rate": 0.0}, {"frequency": 5.0, "growth_rate": 0.0}]
    assert strongest(res) == {"growth_rate": 0.0, "frequency": 3.0, "lowest_frequency": 3.0}
    res = [{"frequency": 0.0, "growth_rate": 2.0}, {"frequency": 4.0, "growth_rate": 0.5}, {"frequency": 7.0, "growth_rate": 0.0}]
    assert strongest(res) == {"growth_rate": 2.0, "frequency": 0.0, "lowest_frequency": 7.0}
    res = [{"frequency": 4.0, "growth_rate": 0.5}, {"frequency": 6.0, "growth_rate": 0.0}]  # flutter
    assert strongest(res) == {"growth_rate": 0.5, "frequency": 4.0, "lowest_frequency": 6.0}


# -- sweeps on a local cluster ------------------------------------------------------------------------


def _coarse_shaft(tmp_path):
    """examples/spinning_shaft.toml with 10 elements."""
    text = (EXAMPLES / "spinning_shaft.toml").read_text().replace("nodes = 41", "nodes = 11")
    assert "nodes = 11" in text
    f = tmp_path / "shaft.toml"
    f.write_text(text)
    return f


def test_modes_sweep_of_the_spinning_shaft(tmp_path, capsys):
    """Lowest frequency against the spin rate, seen from the spinning frame (docs/validation.md, "Spinning shaft"):
    at rest the first bending frequency; spinning, the forward whirl |w_f - Omega| (theory: varint.exact.beams.spinning_shaft_whirl).
    The same table from 1 worker as from 2."""
    scene = _coarse_shaft(tmp_path)
    out = tmp_path / "sweep"
    args = ["sweep", str(scene), "--vary", f"{SPIN_KEY}=0,30,60", "--analysis", "modes", "-n", "6"]
    assert main(args + ["--out", str(out), "--workers", "2"]) == 0
    line = capsys.readouterr().out.strip()
    assert line == f"wrote {out / 'sweep.csv'}: 3 points (3 computed, 0 already done): 3 ok, 0 failed"
    cols, rows = _table(out / "sweep.csv")
    assert cols == [SPIN_KEY, "growth_rate", "frequency", "lowest_frequency", "point", "status", "error"]
    assert [float(r[SPIN_KEY]) for r in rows] == [0.0, 30.0, 60.0]
    assert [r["status"] for r in rows] == ["ok"] * 3 and [r["point"] for r in rows] == ["0", "1", "2"]
    for r in rows:
        assert all(math.isfinite(float(r[c])) for c in ("growth_rate", "frequency", "lowest_frequency"))
        assert float(r["growth_rate"]) == 0.0  # supercritical, yet gyroscopically stable
    low = [float(r["lowest_frequency"]) for r in rows]

    def forward(spin):  # pinned-pinned Timoshenko shaft, first bending mode, forward whirl seen from the spinning frame
        wf, _ = spinning_shaft_whirl(math.pi, 0.3, 1e-3, 2e-3, 2.0, 8e3, spin)
        return abs(wf - spin)

    assert low[0] == pytest.approx(forward(0.0), rel=1e-2)  # 10 elements: 0.4 % (measured)
    assert low[2] == pytest.approx(forward(60.0), rel=1e-2)
    assert low[1] == pytest.approx(forward(30.0), rel=5e-2)  # near the critical speed: |w_f - Omega| is small
    assert low[1] < 0.2 * low[0]  # the forward whirl seen from the shaft slows down to the critical speed...
    assert low[2] > low[0]  # ...and beyond it rises again
    # one worker: the same table, to the last digit
    out1 = tmp_path / "sweep1"
    assert main(args + ["--out", str(out1), "--workers", "1"]) == 0
    assert (out1 / "sweep.csv").read_text() == (out / "sweep.csv").read_text()


def _tiny_tube(tmp_path):
    d = gas_scene(nodes=9, parcels=8, h=1e-5, end=1e-4,
                  perturbation=[{"field": "pressure", "shape": "gaussian", "amplitude": 2000.0, "center": 0.5, "width": 0.1}])
    f = tmp_path / "tube.toml"
    f.write_text(dict_to_toml(d))
    return f


def test_run_sweep_records_a_failing_point_and_a_rerun_skips_finished_points(tmp_path, capsys):
    scene = _tiny_tube(tmp_path)
    out = tmp_path / "runs"
    # time.max_iterations = 1: Newton cannot converge in one iteration, the run fails at its first step
    args = ["sweep", str(scene), "--vary", "fluid.perturbation[0].amplitude=1000,2000", "--analysis", "run",
            "--out", str(out), "--workers", "2"]
    assert main(args + ["--vary", "time.max_iterations=25,1"]) == 0
    line = capsys.readouterr().out.strip()
    assert line == f"wrote {out / 'sweep.csv'}: 4 points (4 computed, 0 already done): 2 ok, 2 failed"
    cols, rows = _table(out / "sweep.csv")
    assert cols[:2] == ["fluid.perturbation[0].amplitude", "time.max_iterations"]
    assert cols[-4:] == ["point", "status", "error", "file"]
    for c in ("energy", "mass", "energy_relative_deviation", "mass_relative_deviation", "newton_iterations_max", "t_end"):
        assert c in cols
    assert [(r["fluid.perturbation[0].amplitude"], r["time.max_iterations"], r["status"]) for r in rows] == [
        ("1000.0", "25", "ok"), ("1000.0", "1", "failed"), ("2000.0", "25", "ok"), ("2000.0", "1", "failed")]
    for r in rows:
        if r["status"] == "ok":
            assert r["error"] == "" and float(r["t_end"]) == pytest.approx(1e-4)
            # relative to the energy that moves (the pulse's), not to |E0| (the gas's internal energy): varint info
            assert float(r["energy_relative_deviation"]) < 1e-7 and math.isfinite(float(r["energy"]))
            assert (out / r["file"]).exists() and r["file"] == f"point_{int(r['point']):04d}.h5"
        else:
            assert r["error"].startswith("Newton failed at step 1") and "\n" not in r["error"]
            assert r["energy"] == ""
    # a re-run with one more value computes only the new points; the finished rows (ok and failed) are kept
    stamp = {r["file"]: (out / r["file"]).stat().st_mtime_ns for r in rows if r["status"] == "ok"}
    assert main(args + ["--vary", "time.max_iterations=25,1,30"]) == 0
    line = capsys.readouterr().out.strip()
    assert line == f"wrote {out / 'sweep.csv'}: 6 points (2 computed, 4 already done): 4 ok, 2 failed"
    _, rows2 = _table(out / "sweep.csv")
    assert rows2[:4] == rows
    assert [(r["time.max_iterations"], r["point"], r["status"]) for r in rows2[4:]] == [("30", "4", "ok"), ("30", "5", "ok")]
    assert {f: (out / f).stat().st_mtime_ns for f in stamp} == stamp  # not run again
    # the same sweep once more: nothing to compute (no cluster needed)
    assert main(args + ["--vary", "time.max_iterations=25,1,30"]) == 0
    assert "(0 computed, 6 already done)" in capsys.readouterr().out
