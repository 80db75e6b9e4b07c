"""What a new user hit in 0.2 (issue 24), beyond the one-line refusals of tests/test_hostile_inputs.py: a failed run
that looked finished, a first run that looked hung, the Ctrl-C hint on the progress bar's line, `varint info` on a
static file and on invariants the model does not have, an end time that is not a multiple of the step, output
folders checked only after the work, and files twenty times the size of their data."""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from varint import parse_scene, run_scene
from varint.cli import main
from varint.errors import OutputError, SolverError
from varint.run.io import read_run, summary
from varint.scene.standard import LIQUID, coupled_scene, gas_scene, rod_scene
from varint.scene.text import to_toml

from helpers import read_only_dir

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


def _gas(tmp_path, name="gas.toml", every=5, **kw):
    d = gas_scene(nodes=9, parcels=8, **({"end": 2e-4} | kw))
    d["output"] = {"every": every}
    f = tmp_path / name
    f.write_text(to_toml(d))
    return f


def _sha(p):
    return hashlib.sha256(Path(p).read_bytes()).hexdigest()


def _err_lines(capsys):
    return capsys.readouterr().err.strip().splitlines()


@pytest.fixture
def fail_at(monkeypatch):
    """``fail_at(n, exc)``: the step from level n raises ``exc`` (default: Newton's failure)."""
    from varint.run import simulation

    real = simulation.Simulation.step

    def arm(n, exc=None):
        def step(self):
            if self.state.n == n:
                raise exc if exc is not None else SolverError(
                    f"step {n + 1} (t = {(n + 1) * self.h:.6g} s): Newton did not converge (diverging)")
            return real(self)

        monkeypatch.setattr(simulation.Simulation, "step", step)

    yield arm
    monkeypatch.setattr(simulation.Simulation, "step", real)


# -- the run file says how the run went ---------------------------------------------------------------------------


def test_a_finished_run_says_so(tmp_path, capsys):
    f = _gas(tmp_path)
    out = tmp_path / "o.h5"
    assert main(["run", str(f), "-o", str(out), "-q"]) == 0
    with h5py.File(out, "r") as h:
        assert h.attrs["status"] == "finished" and "status_message" not in h.attrs
    capsys.readouterr()
    assert main(["info", str(out)]) == 0
    text = capsys.readouterr().out
    assert "\nkind: run\n" in text and "\nstatus: finished\n" in text


def test_a_failed_run_says_where_and_why_and_is_not_resumed(tmp_path, capsys, fail_at):
    f = _gas(tmp_path)
    out = tmp_path / "o.h5"
    fail_at(12)
    assert main(["run", str(f), "-o", str(out), "-q"]) == 2
    line = _err_lines(capsys)
    assert len(line) == 1 and "step 13" in line[0]
    with h5py.File(out, "r") as h:
        a = dict(h.attrs)
    assert a["status"] == "failed" and a["status_step"] == 13 and a["status_time"] == pytest.approx(1.3e-4)
    assert "Newton did not converge" in a["status_message"] and not a["status_resumable"]
    run = read_run(out)  # what was written before the failure is kept: records at steps 0, 5, 10
    assert np.allclose(run["time"], [0.0, 5e-5, 1e-4])
    assert main(["info", str(out)]) == 0
    status = [x for x in capsys.readouterr().out.splitlines() if x.startswith("status:")]
    assert len(status) == 1 and "failed at step 13 (t = 0.00013 s): step 13" in status[0]
    assert "Newton did not converge" in status[0] and "cannot be resumed" in status[0]
    assert main(["info", str(out), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["status_step"] == 13 and "Newton" in d["status_message"]
    # --resume is refused in one line (the same steps would fail the same way), and the file is left as it was
    before = _sha(out)
    assert main(["run", str(f), "-o", str(out), "-q", "--resume"]) == 2
    line = _err_lines(capsys)
    assert len(line) == 1 and str(out) in line[0] and "failed at step 13" in line[0] and "cannot be resumed" in line[0]
    assert _sha(out) == before
    # the API refuses it too
    with pytest.raises(OutputError, match="cannot be resumed"):
        run_scene(parse_scene(f.read_text()), str(out), resume=True, progress=False)
    assert _sha(out) == before


def test_a_run_that_failed_writing_its_file_resumes(tmp_path, capsys, monkeypatch):
    from varint.run.io import RunWriter

    f = _gas(tmp_path)
    out = tmp_path / "o.h5"
    real = RunWriter.append
    calls = []

    def append(self, t, *a, **k):
        calls.append(t)
        if len(calls) == 3:
            raise OutputError(f"{self.path}: write failed (No space left on device)")
        return real(self, t, *a, **k)

    monkeypatch.setattr(RunWriter, "append", append)
    assert main(["run", str(f), "-o", str(out), "-q"]) == 2
    with h5py.File(out, "r") as h:
        assert h.attrs["status"] == "failed" and h.attrs["status_resumable"] and int(h.attrs["records"]) == 2
    monkeypatch.setattr(RunWriter, "append", real)
    capsys.readouterr()
    assert main(["info", str(out)]) == 0
    assert "--resume continues it once the file can be written" in capsys.readouterr().out
    assert main(["run", str(f), "-o", str(out), "-q", "--resume"]) == 0
    with h5py.File(out, "r") as h:
        assert h.attrs["status"] == "finished" and "status_step" not in h.attrs
    assert len(read_run(out)["time"]) == 5


def test_an_interrupted_run_says_so_and_resumes(tmp_path, capsys, fail_at):
    f = _gas(tmp_path)
    out = tmp_path / "o.h5"
    fail_at(12, KeyboardInterrupt())
    assert main(["run", str(f), "-o", str(out), "-q"]) == 130
    with h5py.File(out, "r") as h:
        assert h.attrs["status"] == "interrupted" and h.attrs["status_step"] == 12
    capsys.readouterr()
    assert main(["info", str(out)]) == 0
    assert "status: interrupted at step 12 (t = 0.00012 s): interrupted (Ctrl-C); --resume continues it" in capsys.readouterr().out


def test_a_bug_in_a_step_is_a_traceback_and_the_file_says_failed(tmp_path, fail_at):
    f = _gas(tmp_path)
    out = tmp_path / "o.h5"
    fail_at(7, RuntimeError("a bug"))
    with pytest.raises(RuntimeError):
        main(["run", str(f), "-o", str(out), "-q"])
    with h5py.File(out, "r") as h:
        assert h.attrs["status"] == "failed" and h.attrs["status_message"] == "RuntimeError: a bug"
        assert h.attrs["status_step"] == 8
    assert len(read_run(out)["time"]) == 2


def test_a_file_that_could_not_be_created_is_not_left_behind(tmp_path, capsys, monkeypatch):
    """0.1 left a 6 kB file that info could not read, --resume refused and a rerun refused because it existed."""
    from varint.run.io import RunWriter

    def broken(self, *a):
        raise ValueError("VLEN strings do not support embedded NULLs")

    monkeypatch.setattr(RunWriter, "_create", broken)
    f = _gas(tmp_path)
    out = tmp_path / "o.h5"
    with pytest.raises(ValueError):
        main(["run", str(f), "-o", str(out), "-q"])
    assert not out.exists()


# -- the first run and Ctrl-C on a terminal -----------------------------------------------------------------------


def test_ctrl_c_prints_its_hint_below_the_closed_bar(tmp_path, capsys, monkeypatch, fail_at):
    f = _gas(tmp_path, end=3e-4)
    out = tmp_path / "o.h5"
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True)  # the progress bar, as on a terminal
    fail_at(12, KeyboardInterrupt())
    assert main(["run", str(f), "-o", str(out)]) == 130
    err = capsys.readouterr().err
    head, sep, tail = err.partition("varint: interrupted;")
    assert sep, err
    assert head.endswith("\n"), repr(err[-400:])  # the bar's line was ended before the hint
    assert "12/30" in head.rsplit("\n", 2)[-2]  # the bar's last state stays, on its own line
    assert tail.count("\n") == 1 and tail.endswith("--resume)\n"), repr(tail)  # nothing redrawn after the hint


def test_a_cold_kernel_cache_is_announced_once(tmp_path, capsys, monkeypatch):
    """numba announces each compilation; a kernel seen for the first time (here one made for the test, as a cold
    cache would have them all) prints one line, a warm one none, and -q none."""
    import numba

    from varint.run import simulation

    @numba.njit(cache=False)
    def fresh(x):
        return x + 1.0

    real = simulation.Simulation.step

    def step(self):
        fresh(1.0)
        return real(self)

    monkeypatch.setattr(simulation.Simulation, "step", step)
    f = _gas(tmp_path)
    assert main(["run", str(f), "-o", str(tmp_path / "a.h5")]) == 0
    err = capsys.readouterr().err.splitlines()
    notes = [x for x in err if "compiling kernels" in x]
    assert notes == ["varint: compiling kernels (first run only; they are cached on disk afterwards)..."], err
    assert main(["run", str(f), "-o", str(tmp_path / "b.h5")]) == 0  # compiled now: no note
    assert "compiling" not in capsys.readouterr().err


@pytest.mark.slow  # about 2 min: every kernel of the rod compiled from an empty cache
def test_a_cold_first_run_says_it_compiles(tmp_path):
    scene = tmp_path / "tumbling.toml"
    scene.write_text((EXAMPLES / "tumbling_rod.toml").read_text())
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    for k, expected in ((1, True), (2, False)):
        proc = subprocess.run([sys.executable, "-m", "varint", "run", str(scene), "-o", str(tmp_path / f"{k}.h5")],
                              capture_output=True, text=True, env=env, timeout=900)
        assert proc.returncode == 0, proc.stderr[-2000:]
        assert ("compiling kernels (first run only" in proc.stderr) == expected, proc.stderr


# -- varint info: what the file is, and the invariants the model has ----------------------------------------------


def test_info_of_a_static_file_says_it_is_static(tmp_path, capsys):
    f = tmp_path / "rod.toml"
    f.write_text(to_toml({"title": "rod", "tube": {"length": 1.0, "nodes": 6, "radius": 0.01},
                          "rod": {"mass_per_length": 0.3, "rotary_inertia": 1e-4, "bending_stiffness": 2.0,
                                  "torsional_stiffness": 1.5, "axial_stiffness": 1e3, "shear_stiffness": 8e2,
                                  "ends": {"s0": "clamped", "sL": "free"}, "load": {"force": [0.0, -0.1, 0.0]}},
                          "time": {"step": 1e-3, "end": 2e-3}}))
    out = tmp_path / "s.h5"
    assert main(["static", str(f), "-o", str(out)]) == 0
    capsys.readouterr()
    assert main(["info", str(out)]) == 0
    text = capsys.readouterr().out
    assert "\nkind: static: one frame written by varint static, the static equilibrium\n" in text
    assert "\nstatus: finished\n" in text and "deviation" not in text


def _momenta(d):
    return sorted(k for k in d if "momentum" in k and k.endswith("_deviation"))


def test_info_prints_the_deviations_of_the_declared_invariants_only(tmp_path):
    # a clamped hose full of water under gravity (the water hose, small): no momentum is an invariant
    hose = coupled_scene(nodes=5, parcels=8, fluid=LIQUID, wall={"model": "quasistatic"}, ends=("clamped", "free"),
                         gravity=[0.0, -9.81, 0.0], dimension=2, end=3e-3)
    run_scene(hose, str(tmp_path / "hose.h5"), progress=False)
    d = summary(tmp_path / "hose.h5")
    assert "linear_momentum" not in d["invariants"] and _momenta(d) == [] and "energy" in d["invariants"]
    # a free rod falling under gravity: the momentum across gravity and the angular momentum along it
    rod = rod_scene(nodes=6, h=1e-3, end=5e-3, gravity=[0.0, -9.81, 0.0],
                    initial={"angular_velocity": [0.0, 2.0, 1.0], "velocity": [0.3, 0.0, 0.0]})
    run_scene(rod, str(tmp_path / "rod.h5"), progress=False)
    d = summary(tmp_path / "rod.h5")
    assert _momenta(d) == ["angular_momentum_along_gravity_deviation", "linear_momentum_transverse_to_gravity_deviation"]
    assert d["linear_momentum_transverse_to_gravity_deviation"] < 1e-12
    assert d["angular_momentum_along_gravity_deviation"] < 1e-12
    P = read_run(tmp_path / "rod.h5")["monitors"]["linear_momentum"]
    assert abs(P[-1, 1] - P[0, 1]) > 1e-3  # the momentum along gravity changes: it is not printed


def test_energy_deviation_is_relative_to_the_energy_that_moves(tmp_path):
    """|E0| of air in a rubber tube is its internal energy, ~10^6 times the pulse's: relative to it any error
    looks small.  The reference is the largest kinetic energy plus the largest change of the potential energy."""
    d = gas_scene(nodes=17, parcels=16, end=2e-4, perturbation=[{"field": "pressure", "shape": "gaussian",
                                                                "amplitude": 2000.0, "center": 0.5, "width": 0.1}])
    out = tmp_path / "pulse.h5"
    run_scene(parse_scene(to_toml(d)), str(out), progress=False)
    mon = read_run(out)["monitors"]
    E, K = mon["energy"], mon["kinetic_energy"]
    V = E - K
    moving = np.max(K) + np.max(np.abs(V - V[0]))
    assert moving < 1e-4 * abs(E[0])
    s = summary(out)
    assert s["energy_reference"] == pytest.approx(moving, rel=1e-12)
    assert s["energy_relative_deviation"] == pytest.approx(np.max(np.abs(E - E[0])) / moving, rel=1e-12)


# -- end times, output folders ------------------------------------------------------------------------------------


def test_an_end_that_is_not_a_multiple_of_the_step_is_reached_and_said(tmp_path, capsys):
    f = _gas(tmp_path, end=2.05e-4)
    out = tmp_path / "o.h5"
    assert main(["run", str(f), "-o", str(out), "-q"]) == 0
    cap = capsys.readouterr()
    note = "time.end = 0.000205 s is not a multiple of time.step = 1e-05 s: the run takes 21 steps and ends at t = 0.00021 s"
    assert cap.err.strip() == f"varint: note: {note}"
    assert read_run(out)["time"][-1] == pytest.approx(2.1e-4, rel=1e-12)
    assert main(["check", str(f)]) == 0
    text = capsys.readouterr().out
    assert "end = 0.000205 s (21 steps)" in text and f"note: {note}" in text
    # a multiple of the step up to round-off (2e-4 / 1e-5 = 20.000000000000004): no note, 20 steps
    assert parse_scene(to_toml(gas_scene(end=2e-4))).end_note is None
    assert parse_scene(to_toml(gas_scene(end=2e-4))).steps == 20
    garden = parse_scene((EXAMPLES / "garden_hose.toml").read_text())
    assert garden.steps == 3637 and "ends at t = 2.00035 s" in garden.end_note  # 0.2 stopped at 1.9998 s


@pytest.fixture
def read_only(tmp_path):
    undo = read_only_dir(tmp_path / "ro")
    if undo is None:
        pytest.skip("no read-only folder can be made here")
    yield tmp_path / "ro"
    undo()


def _never(*a, **k):
    raise AssertionError("the work started before the output was checked")


def test_output_folders_are_checked_before_any_work(tmp_path, capsys, monkeypatch, read_only):
    import varint.model.model
    import varint.plotting
    import varint.sweep

    f = _gas(tmp_path)
    out = tmp_path / "o.h5"
    assert main(["run", str(f), "-o", str(out), "-q"]) == 0
    capsys.readouterr()
    monkeypatch.setattr(varint.model.model, "build_model", _never)
    monkeypatch.setattr(varint.plotting, "plot_run", _never)
    monkeypatch.setattr(varint.sweep, "sweep", _never)
    rod = tmp_path / "rod.toml"
    rod.write_text((EXAMPLES / "cantilever_rod.toml").read_text())
    for argv, path in ((["static", str(rod), "-o", str(read_only / "s.h5")], read_only / "s.h5"),
                       (["run", str(f), "-o", str(read_only / "r.h5"), "-q"], read_only / "r.h5"),
                       (["plot", str(out), "-d", str(read_only)], read_only),
                       (["plot", str(out), "-d", str(read_only / "pics")], read_only / "pics"),
                       (["plot", str(out), "-d", str(f)], f),
                       (["sweep", str(f), "--vary", "fluid.velocity=0,1", "--analysis", "run", "--out",
                         str(read_only / "x")], read_only / "x"),
                       (["sweep", str(f), "--vary", "fluid.velocity=0,1", "--analysis", "run", "--out", str(f)], f)):
        assert main(argv) == 2, argv
        line = _err_lines(capsys)
        assert len(line) == 1 and line[0].startswith(f"varint: error: {path}: "), line


# -- file sizes ---------------------------------------------------------------------------------------------------


def _data_bytes(path):
    with h5py.File(path, "r") as h:
        total = []
        h.visititems(lambda n, o: total.append(o.id.get_storage_size()) if isinstance(o, h5py.Dataset) else None)
        return sum(total)


def test_a_short_run_file_is_about_the_size_of_its_data(tmp_path):
    """0.2: a 10-step, 20-parcel file was 1.4 MB (chunks of 1024 records, allocated whole), Sod's 5.4 MB for 176 kB."""
    d = gas_scene(nodes=21, parcels=20, end=1e-4)
    d["output"] = {"every": 1}
    out = tmp_path / "small.h5"
    run_scene(parse_scene(to_toml(d)), str(out), progress=False)
    assert os.path.getsize(out) < 150_000
    assert _data_bytes(out) < 25_000
    with h5py.File(out, "r") as h:
        for name in ("fields/fluid/pressure", "monitors/energy", "time"):
            assert h[name].chunks[0] == 11  # the run's records, no more
    # many records: chunks of at most 64 kB, each a few records of a large field
    d = gas_scene(nodes=401, parcels=400, wall=False, end=3e-5, h=1e-6)
    d["output"] = {"every": 1}
    out = tmp_path / "wide.h5"
    run_scene(parse_scene(to_toml(d)), str(out), progress=False)
    with h5py.File(out, "r") as h:
        c = h["fields/fluid/pressure"].chunks
        assert c == (20, 400) and 8 * c[0] * c[1] <= 64 * 1024
        data = sum(8 * np.prod(h[f"fields/fluid/{k}"].shape) for k in ("pressure", "density", "entropy", "s", "velocity"))
    assert os.path.getsize(out) < 1.6 * data + 150_000


def test_the_gas_law_overflows_to_inf_not_to_an_exception():
    """0.2: fluid.density = 1e300 was an OverflowError in IdealGas.entropy (Python's float power); numpy's gives inf,
    which the validation names (fluid.density, tests/test_hostile_inputs.py) and the solvers' finiteness tests catch."""
    from varint.terms.thermo import IdealGas

    gas = IdealGas(1.4, 287.05)
    with np.errstate(all="ignore"):
        assert gas.entropy(1e300, 101325.0) == -np.inf
        assert gas.pressure(1e300, 0.0) == np.inf
        assert gas.density(1e300, -1e6) == np.inf
    assert gas.entropy(1.2, 1e5) == pytest.approx(717.625 * np.log(1e5 / 1.2 ** 1.4), rel=1e-15)
