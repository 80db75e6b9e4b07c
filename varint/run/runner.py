"""Run a scene to its end time, writing the HDF5 run file as it goes."""

from __future__ import annotations

import logging
import math
import os
import sys
from pathlib import Path

from ..errors import OutputError
from .io import RunWriter
from ..model.model import build_model
from .simulation import Simulation

__all__ = ["run_scene", "default_output", "check_output", "make_simulation"]


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
        return
    if p.exists() and not force:
        how = "continue it with --resume or replace it with --force" if resumable else "replace it with --force"
        raise OutputError(f"{out}: exists; {how}")


def _select(fields, groups):
    if groups is None:
        return fields
    return {k: v for k, v in fields.items() if k.split("/")[0] in groups}


def run_scene(scene, out, resume=False, progress=None, max_steps=None):
    """Integrate ``scene`` from t = 0 (or from the file's checkpoint) to ``time.end``.

    Parameters
    ----------
    out : str
        Run file path.
    resume : bool
        Continue an interrupted file instead of starting anew.
    progress : bool, optional
        Show a progress bar (default: when stderr is a terminal).
    max_steps : int, optional
        Stop after this many steps of this call (for tests and benchmarks).

    Returns
    -------
    Simulation
        The simulation at its final state.
    """
    model = build_model(scene)
    sim = make_simulation(model)
    every = scene.output.every
    groups = scene.output.fields
    n_end = int(math.floor(scene.time.end / sim.h + 1e-9))
    writer = RunWriter(out, scene, sim.h, sim.monitors(), _select(sim.fields(), groups), resume=resume)
    try:
        if resume:
            sim.state = writer.checkpoint_state()
            log.info("resuming %s at step %d (t = %g s)", out, sim.state.n, sim.state.t)
        else:
            writer.append(0.0, sim.monitors(), _select(sim.fields(), groups), sim.state)
        if progress is None:
            progress = sys.stderr.isatty()
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=n_end, initial=sim.state.n, unit="step", desc=Path(out).name, file=sys.stderr)
        steps = 0
        while sim.state.n < n_end and (max_steps is None or steps < max_steps):
            sim.step()
            steps += 1
            if sim.state.n % every == 0 or sim.state.n == n_end:
                writer.append(sim.state.t, sim.monitors(), _select(sim.fields(), groups), sim.state)
                # a restart starts with a fresh Jacobian: do the same here so both runs repeat the same arithmetic
                sim.invalidate_jacobian()
            if bar is not None:
                bar.update(1)
        if bar is not None:
            bar.close()
    finally:
        writer.close()
    return sim
