"""What a new user hits on the command line: files that must not be lost, wrong counts, closed
pipes, Ctrl-C, resuming a static file, modes of a loaded rod, a missing directory, a binary scene."""

import json
import subprocess
import sys
from pathlib import Path

import h5py
import pytest

from varint import parse_scene
from varint.cli import main
from varint.run.io import read_run
from varint.run.runner import default_output

from varint.scene.standard import gas_scene
from varint.scene.text import to_toml

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


def _gas(tmp_path, name="scene.toml", end=2e-4, **output):
    d = gas_scene(nodes=9, parcels=8, end=end)
    d["output"] = {"every": 5, **output}
    f = tmp_path / name
    f.write_text(to_toml(d))
    return f


def _cantilever(tmp_path, load=True):
    """The cantilever example on 5 elements (the tip load kept, or removed)."""
    t = (EXAMPLES / "cantilever_rod.toml").read_text()
    for a, b in (("nodes = 51", "nodes = 6"), ("end = 4.0", "end = 0.02"), ("every = 10", "every = 2")):
        assert a in t
        t = t.replace(a, b)
    if not load:
        assert "[rod.load]\nforce = [0.0, -0.031415926535897934, 0.0]\n" in t
        t = t.replace("[rod.load]\nforce = [0.0, -0.031415926535897934, 0.0]\n", "")
    f = tmp_path / ("cantilever.toml" if load else "unloaded.toml")
    f.write_text(t)
    return f


def _one_error_line(capsys):
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("varint: error: "), err
    return err[0]


# -- -o never loses a file -----------------------------------------------------------------------


def test_run_refuses_an_existing_output(tmp_path, capsys):
    f = _gas(tmp_path)
    other = tmp_path / "precious.h5"
    other.write_bytes(b"someone's data")
    assert main(["run", str(f), "-o", str(other), "-q"]) == 2
    line = _one_error_line(capsys)
    assert str(other) in line and "--resume" in line and "--force" in line
    assert other.read_bytes() == b"someone's data"
    assert main(["run", str(f), "-o", str(other), "-q", "--force"]) == 0  # replaced on request
    assert len(read_run(other)["time"]) == 5


def test_the_scene_file_is_never_the_output(tmp_path, capsys):
    f = _gas(tmp_path)
    text = f.read_text()
    for extra in ([], ["--force"], ["--resume"]):
        assert main(["run", str(f), "-o", str(f), "-q", *extra]) == 2
        assert "scene file itself" in _one_error_line(capsys)
    assert main(["static", str(f), "-o", str(f), "--force"]) == 2
    assert "scene file itself" in _one_error_line(capsys)
    # the same file under another name
    assert main(["run", str(f), "-o", str(tmp_path / "." / f.name), "-q", "--force"]) == 2
    assert "scene file itself" in _one_error_line(capsys)
    assert f.read_text() == text


def test_the_default_output_is_checked_too(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    f = _gas(tmp_path)
    assert main(["run", f.name, "-q"]) == 0
    out = tmp_path / "scene.h5"
    first = read_run(out)["time"]
    assert main(["run", f.name, "-q"]) == 2
    line = _one_error_line(capsys)
    assert "scene.h5" in line and "--force" in line
    assert main(["run", f.name, "-q", "--resume"]) == 0  # this scene's run: resuming it is allowed
    assert len(read_run(out)["time"]) == len(first)
    assert main(["run", f.name, "-q", "--force"]) == 0


def test_resume_needs_the_file(tmp_path, capsys):
    f = _gas(tmp_path)
    assert main(["run", str(f), "-o", str(tmp_path / "none.h5"), "-q", "--resume"]) == 2
    assert "no such run file to resume" in _one_error_line(capsys)


def test_static_refuses_an_existing_output_and_names_its_default_apart(tmp_path, capsys):
    f = _cantilever(tmp_path)
    out = tmp_path / "s.h5"
    out.write_bytes(b"keep")
    assert main(["static", str(f), "-o", str(out)]) == 2
    line = _one_error_line(capsys)
    assert str(out) in line and "--force" in line and "--resume" not in line
    assert out.read_bytes() == b"keep"
    # [output].file without ".h5": the static file was the run's own name (str.replace found nothing)
    scene = parse_scene(f.read_text().replace("[output]\n", '[output]\nfile = "result.hdf5"\n'))
    assert default_output(scene, str(f)) == "result.hdf5"
    assert default_output(scene, str(f), kind="static") == "result_static.hdf5"


def test_missing_output_directory_is_one_line(tmp_path, capsys):
    f = _gas(tmp_path)
    out = tmp_path / "no" / "such" / "dir" / "o.h5"
    assert main(["run", str(f), "-o", str(out), "-q"]) == 2
    line = _one_error_line(capsys)
    assert line == f"varint: error: {out}: directory {out.parent} does not exist"
    assert main(["static", str(_cantilever(tmp_path)), "-o", str(out)]) == 2
    assert "does not exist" in _one_error_line(capsys)


def test_a_binary_scene_is_one_line(tmp_path, capsys):
    f = tmp_path / "run.h5"
    f.write_bytes(b"\x89HDF\r\n\x1a\n\x00\x00\x00\x00\xff\xfe")
    for cmd in ("check", "run", "modes", "static"):
        assert main([cmd, str(f)]) == 2
        assert _one_error_line(capsys) == f"varint: error: {f}: not a text (UTF-8) TOML file"


def test_unreadable_run_files_are_named_in_words(tmp_path, capsys):
    text = tmp_path / "notes.h5"
    text.write_text("not hdf5")
    assert main(["info", str(text)]) == 2
    assert _one_error_line(capsys) == f"varint: error: {text}: not a readable varint run file (not an HDF5 file)"
    assert main(["info", str(tmp_path / "missing.h5")]) == 2
    assert _one_error_line(capsys).endswith("(No such file or directory)")


# -- modes -------------------------------------------------------------------------------------------


@pytest.mark.parametrize("count", ["-3", "0"])
def test_modes_count_must_be_positive(tmp_path, capsys, count):
    f = _gas(tmp_path)
    assert main(["modes", str(f), "-n", count]) == 2
    line = _one_error_line(capsys)
    assert "-n/--count must be >= 1" in line and count in line
    assert capsys.readouterr().out == ""


@pytest.mark.slow  # 0.5-1.7 min: the slow tier (tests/conftest.py; CI runs it)
def test_modes_of_a_loaded_rod_say_what_they_linearise_about(tmp_path, capsys):
    f = _cantilever(tmp_path)
    assert main(["modes", str(f), "-n", "3"]) == 0
    cap = capsys.readouterr()
    note = cap.err.strip().splitlines()
    assert len(note) == 1 and "has loads (rod.load.force)" in note[0] and "initial, unloaded state" in note[0]
    assert "--about static" in note[0]
    assert len(cap.out.strip().splitlines()) == 3
    assert main(["modes", str(f), "-n", "3", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["about"] == "initial" and "loads" in d["note"] and len(d["modes"]) == 3
    # about the loaded equilibrium, or without loads: no note
    assert main(["modes", str(f), "-n", "3", "--about", "static", "--json"]) == 0
    cap = capsys.readouterr()
    d = json.loads(cap.out)
    assert d["about"] == "static" and "note" not in d and cap.err == ""
    assert main(["modes", str(_cantilever(tmp_path, load=False)), "-n", "3"]) == 0
    assert capsys.readouterr().err == ""


# -- Ctrl-C ------------------------------------------------------------------------------------------


def _interrupt(*a, **k):
    raise KeyboardInterrupt


def test_ctrl_c_in_plot_modes_static_says_interrupted_only(tmp_path, capsys, monkeypatch):
    import varint.model.model
    import varint.plotting

    f = _gas(tmp_path)
    out = tmp_path / "o.h5"
    assert main(["run", str(f), "-o", str(out), "-q"]) == 0
    capsys.readouterr()
    monkeypatch.setattr(varint.plotting, "plot_run", _interrupt)
    assert main(["plot", str(out), "-d", str(tmp_path)]) == 130
    assert capsys.readouterr().err.strip() == "varint: interrupted"
    monkeypatch.setattr(varint.model.model, "build_model", _interrupt)
    assert main(["modes", str(f)]) == 130
    assert capsys.readouterr().err.strip() == "varint: interrupted"
    assert main(["static", str(_cantilever(tmp_path)), "-o", str(tmp_path / "s.h5")]) == 130
    assert capsys.readouterr().err.strip() == "varint: interrupted"


def test_ctrl_c_in_run_names_the_file_and_the_resume(tmp_path, capsys, monkeypatch):
    from varint.run import simulation as stepper

    f = _gas(tmp_path, end=3e-4)
    out = tmp_path / "o.h5"
    real_step = stepper.Simulation.step

    def step(self):
        if self.state.n == 12:
            raise KeyboardInterrupt
        return real_step(self)

    monkeypatch.setattr(stepper.Simulation, "step", step)
    assert main(["run", str(f), "-o", str(out), "-q"]) == 130
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(out) in err[0] and "--resume" in err[0] and "3 complete records" in err[0], err
    monkeypatch.setattr(stepper.Simulation, "step", real_step)
    assert main(["run", str(f), "-o", str(out), "-q", "--resume"]) == 0
    assert len(read_run(out)["time"]) == 7


def test_ctrl_c_before_any_record_does_not_promise_a_resume(tmp_path, capsys, monkeypatch):
    import varint.run.runner

    f = _gas(tmp_path)
    monkeypatch.setattr(varint.run.runner, "build_model", _interrupt)
    assert main(["run", str(f), "-o", str(tmp_path / "o.h5"), "-q"]) == 130
    assert capsys.readouterr().err.strip() == "varint: interrupted"


# -- resume of a static file -------------------------------------------------------------------------


def test_resume_of_a_static_file_is_refused(tmp_path, capsys):
    f = _cantilever(tmp_path)
    out = tmp_path / "static.h5"
    assert main(["static", str(f), "-o", str(out)]) == 0
    capsys.readouterr()
    with h5py.File(out, "r") as h:
        assert h.attrs["static"] and int(h.attrs["records"]) == 1
    assert main(["run", str(f), "-o", str(out), "-q", "--resume"]) == 2
    line = _one_error_line(capsys)
    assert str(out) in line and "varint static" in line and "cannot be resumed" in line
    assert len(read_run(out)["time"]) == 1  # untouched


# -- closed pipe ----------------------------------------------------------------------------------------


def test_info_into_a_closed_pipe_is_quiet(tmp_path):
    f = _gas(tmp_path)
    out = tmp_path / "o.h5"
    assert main(["run", str(f), "-o", str(out), "-q"]) == 0
    # the reader is gone before varint writes a byte (what `varint info F | head -1` can meet)
    proc = subprocess.Popen([sys.executable, "-m", "varint", "info", str(out)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)
    proc.stdout.close()
    err = proc.stderr.read().decode()
    proc.wait(timeout=60)
    assert err == "" and proc.returncode == 141, (proc.returncode, err)
