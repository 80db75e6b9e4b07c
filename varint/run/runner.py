"""Run a scene to its end time, writing the HDF5 run file as it goes."""

from __future__ import annotations

import logging
import os
import sys
import tempfile
from pathlib import Path

from ..errors import OutputError, VarintError
from .io import RunWriter
from ..model.model import build_model
from ..scene.schema import step_count
from .simulation import Simulation

__all__ = ["run_scene", "default_output", "check_output", "check_output_dir", "make_simulation"]


def make_simulation(model):
    """The stepper of a model (one for every model: :class:`varint.run.simulation.Simulation`)."""
    return Simulation(model)

log = logging.getLogger(__name__)


def default_output(scene, path=None, kind=None):
    """The run file of a scene when ``-o`` is not given: ``[output].file``, else the scene file's
    name with ``.h5`` (in the working directory).  ``kind="static"`` gives ``NAME_static.h5``."""
    out = scene.output.file or f"{Path(path).stem if path else 'run'}.h5"
    if kind:
        p = Path(out)
        out = str(p.with_name(f"{p.stem}_{kind}{p.suffix or '.h5'}"))
    return out


def check_output(out, scene_path=None, resume=False, force=False, resumable=True):
    """Refuse an output path that would lose a file, in one line.

    An existing file is replaced only with ``force``; with ``resume`` it must exist (the writer then
    checks that it is this scene's run).  The scene file itself is never an output, even with
    ``force``.  ``resumable=False`` (``varint static``) leaves ``--resume`` out of the advice.
    """
    p = Path(out)
    if scene_path is not None and p.exists() and Path(scene_path).exists() and os.path.samefile(p, scene_path):
        raise OutputError(f"{out}: is the scene file itself; write the run to another file")
    if p.is_dir():
        raise OutputError(f"{out}: is a directory; give a file name")
    parent = p.parent
    if not parent.exists():
        raise OutputError(f"{out}: directory {parent} does not exist")
    if not parent.is_dir():
        raise OutputError(f"{out}: {parent} is not a directory")
    if resume:
        if not p.exists():
            raise OutputError(f"{out}: no such run file to resume")
        why = _unwritable_file(p)
        if why:
            raise OutputError(f"{out}: cannot be written ({why}); it cannot be resumed")
        return
    if p.exists() and not force:
        how = "continue it with --resume or replace it with --force" if resumable else "replace it with --force"
        raise OutputError(f"{out}: exists; {how}")
    why = _unwritable_file(p) if p.exists() else _unwritable_dir(parent)
    if why:
        raise OutputError(f"{out}: cannot be written ({why})" if p.exists() else
                          f"{out}: cannot create a file in {parent} ({why})")


def check_output_dir(path):
    """Refuse, in one line, a folder that a command's output files cannot go into, before anything is computed: a
    path that is a file, a folder that cannot be written, or a missing folder under a file or an unwritable folder
    (a missing folder is created by the command that writes into it)."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise OutputError(f"{path}: is not a directory")
    q = p
    while not q.exists() and q != q.parent:
        q = q.parent
    if not q.is_dir():
        raise OutputError(f"{path}: {q} is not a directory")
    why = _unwritable_dir(q)
    if why:
        raise OutputError(f"{path}: cannot create files in {q} ({why})")


def _reason(exc):
    return os.strerror(exc.errno) if getattr(exc, "errno", None) else exc.__class__.__name__


def _unwritable_dir(d):
    """Why no file can be created in folder ``d`` (tried with a temporary file, which is removed: permissions alone
    do not say it, e.g. for root or on a read-only file system), or None."""
    try:
        fd, name = tempfile.mkstemp(prefix=".varint-probe-", dir=d)
    except OSError as exc:
        return _reason(exc)
    os.close(fd)
    os.unlink(name)
    return None


def _unwritable_file(p):
    """Why the existing file ``p`` cannot be opened for writing (opened and closed, not changed), or None."""
    try:
        with open(p, "r+b"):
            pass
    except OSError as exc:
        return _reason(exc)
    return None


def _select(fields, groups):
    if groups is None:
        return fields
    return {k: v for k, v in fields.items() if k.split("/")[0] in groups}


def _records(n_end, every):
    """Records of a run of ``n_end`` steps writing every ``every`` steps: t = 0, each multiple of every, the end."""
    return n_end // every + 1 + (1 if n_end % every else 0)


class _CompileNote:
    """Says once on stderr that numba compiles kernels (its on-disk cache is cold: the first run after installing or
    changing varint), so that a run sitting at 0 % while it compiles does not look hung.  numba announces every
    compilation as a "numba:compile" event and loads cached kernels without one, so the note appears exactly when
    something is compiled."""

    TEXT = "varint: compiling kernels (first run only; they are cached on disk afterwards)..."

    def __init__(self, show):
        self.show, self.said, self.bar, self.listener = show, False, None, None

    def __enter__(self):
        if self.show:
            from numba.core import event

            note = self

            class Listener(event.Listener):
                def on_start(self, ev):
                    note.say()

                def on_end(self, ev):
                    pass

            self.listener = Listener()
            event.register("numba:compile", self.listener)
        return self

    def say(self):
        if self.said:
            return
        self.said = True
        if self.bar is not None:
            self.bar.write(self.TEXT, file=sys.stderr)  # above the bar, which is redrawn below it
        else:
            print(self.TEXT, file=sys.stderr, flush=True)

    def __exit__(self, *exc):
        if self.listener is not None:
            from numba.core import event

            event.unregister("numba:compile", self.listener)
        return False


def _one_line(exc):
    """An exception as the one line the run file keeps."""
    text = str(exc).strip() or exc.__class__.__name__
    text = "; ".join(line.strip() for line in text.splitlines() if line.strip())
    return text if isinstance(exc, VarintError) else f"{exc.__class__.__name__}: {text}"


def run_scene(scene, out, resume=False, progress=None, max_steps=None):
    """Integrate ``scene`` from t = 0 (or from the file's checkpoint) to ``time.end``.

    The run file says how the run went in its root attribute ``status`` (docs/output.md): ``running`` while it
    goes, then ``finished``, ``interrupted`` (Ctrl-C, or ``max_steps``) or ``failed``, with the step, the time and
    the one-line message of the failure or interruption; the records written before a failure stay in the file.

    Parameters
    ----------
    out : str
        Run file path.
    resume : bool
        Continue an interrupted file instead of starting anew (a failed one is refused: varint.run.io.check_resumable).
    progress : bool, optional
        Show a progress bar (default: when stderr is a terminal).  Unless ``progress`` is False, a line on stderr
        says when numba compiles the kernels (a cold cache).
    max_steps : int, optional
        Stop after this many steps of this call (for tests and benchmarks).

    Returns
    -------
    Simulation
        The simulation at its final state.
    """
    if progress is None:
        progress = sys.stderr.isatty()
        note = _CompileNote(show=True)
    else:
        note = _CompileNote(show=bool(progress))
    with note:
        return _run(scene, out, resume, progress, max_steps, note)


def _run(scene, out, resume, progress, max_steps, note):
    model = build_model(scene)
    sim = make_simulation(model)
    every = scene.output.every
    groups = scene.output.fields
    n_end = scene.steps if sim.h == scene.time.step else step_count(scene.time.end, sim.h)
    writer = RunWriter(out, scene, sim.h, sim.monitors(), _select(sim.fields(), groups), resume=resume,
                       records=_records(n_end, every), invariants=model.invariants(), scheme=sim.scheme.name)
    bar = None
    at = None  # the step being computed (None: between steps)
    try:
        if resume:
            sim.state = writer.checkpoint_state()
            log.info("resuming %s at step %d (t = %g s)", out, sim.state.n, sim.state.t)
        else:
            writer.append(0.0, sim.monitors(), _select(sim.fields(), groups), sim.state)
        if progress:
            from tqdm import tqdm

            bar = note.bar = tqdm(total=n_end, initial=sim.state.n, unit="step", desc=Path(out).name, file=sys.stderr)
        steps = 0
        while sim.state.n < n_end and (max_steps is None or steps < max_steps):
            at = sim.state.n + 1
            sim.step()
            at = None
            steps += 1
            if sim.state.n % every == 0 or sim.state.n == n_end:
                writer.append(sim.state.t, sim.monitors(), _select(sim.fields(), groups), sim.state)
                # a restart starts with a fresh Jacobian: do the same here so both runs repeat the same arithmetic
                sim.invalidate_jacobian()
            if bar is not None:
                bar.update(1)
        if sim.state.n >= n_end:
            writer.set_status("finished")
        else:
            writer.set_status("interrupted", step=sim.state.n, time=sim.state.t,
                              message=f"stopped after max_steps = {max_steps} steps")
    except KeyboardInterrupt:
        _close(bar)  # the bar's last state stays on its own line; the caller's message goes below it
        bar = None
        writer.set_status("interrupted", step=sim.state.n, time=sim.state.t, message="interrupted (Ctrl-C)")
        raise
    except BaseException as exc:
        _close(bar)
        bar = None
        n = sim.state.n if at is None else at
        writer.set_status("failed", step=n, time=n * sim.h, message=_one_line(exc),
                          resumable=isinstance(exc, OutputError))
        raise
    finally:
        _close(bar)
        writer.close()
    return sim


def _close(bar):
    if bar is not None:
        try:
            bar.close()
        except Exception:  # noqa: BLE001 - a terminal gone away must not hide the run's own error
            pass
