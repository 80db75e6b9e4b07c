"""``varint sweep``: one scene over the product of values of some of its keys, on a Dask cluster.

A sweep point is the scene's TOML text with the varied keys set (parsed with ``tomllib``, the
values set, written back by :func:`to_toml`).  Every point is validated by
:func:`varint.parse_scene` before anything runs.  Each point is then one task on a
``dask.distributed`` cluster (a local one, one single-threaded worker process per core, or an
existing one by its scheduler's address): ``run`` integrates it into ``DIR/point_NNNN.h5``,
``modes`` computes its modes as ``varint modes`` does (:func:`varint.analysis.modes.scene_modes`).
``DIR/sweep.csv`` gets one row per point as the points finish (docs/output.md); a point that fails
with a :class:`~varint.VarintError` is a row with its one-line error; a re-run skips the points already in
the table (by their key values).
"""

from __future__ import annotations

import csv
import itertools
import json
import math
import os
import sys
import tomllib
from pathlib import Path

import numpy as np

from .errors import OutputError, SceneError, VarintError
from .scene.text import KeyPathError, resolve_key, set_key, to_toml

__all__ = ["Vary", "parse_vary", "resolve_key", "set_key", "to_toml", "point_texts", "sweep", "compute_point", "finished_points", "point_numbers"]

ANALYSES = ("run", "modes")
#: result columns of the modes analysis (docs/output.md)
MODES_COLUMNS = ("growth_rate", "frequency", "lowest_frequency")
#: the columns after the results
TAIL_COLUMNS = ("point", "status", "error", "file")


class SweepError(VarintError):
    """A sweep that cannot start: a bad --vary, an invalid point, a table of another sweep."""


# ---------------------------------------------------------------------------
# keys


class Vary:
    """One ``--vary`` option resolved against the scene schema.

    ``key``: as written (the CSV column); ``path``: ``[(name, index or None), ...]``;
    ``decl``: the ``varint.scene.schema.Key`` declaration; ``values``: the values, typed by its kind.
    """

    def __init__(self, key, path, decl, values):
        self.key, self.path, self.decl, self.values = key, path, decl, values

    def __repr__(self):  # pragma: no cover - debugging aid
        return f"Vary({self.key!r}, {self.values!r})"


def _number(text, decl, key):
    try:
        x = float(text)
    except ValueError:
        raise SweepError(f"--vary {key}: {text.strip()!r} is not a number") from None
    if not math.isfinite(x):
        raise SweepError(f"--vary {key}: {text.strip()!r} is not a finite number")
    if decl.kind == "int":
        if not x.is_integer():
            raise SweepError(f"--vary {key}: is a whole number, got {text.strip()}")
        return int(x)
    return x


def parse_vary(spec):
    """``KEY=START:STOP:NUM`` (NUM values from START to STOP, inclusive) or ``KEY=V1,V2,...`` -> :class:`Vary`.

    Numbers are floats, or ints when the scene key is an int; a string key takes a comma list.
    Raises ``SweepError`` naming the option.
    """
    if "=" not in spec:
        raise SweepError(f"--vary {spec}: expected KEY=START:STOP:NUM or KEY=V1,V2,...")
    key, _, rhs = spec.partition("=")
    key = key.strip()
    if not key:
        raise SweepError(f"--vary {spec}: no key before '='")
    path, decl = resolve_key(key)
    rhs = rhs.strip()
    if not rhs:
        raise SweepError(f"--vary {key}: no values after '='")
    if ":" in rhs:
        parts = rhs.split(":")
        if len(parts) != 3:
            raise SweepError(f"--vary {key}: a range is START:STOP:NUM, got {rhs!r}")
        if decl.kind == "str":
            raise SweepError(f"--vary {key}: is a string; give a comma list of values")
        start, stop = (_number(p, _FLOAT, key) for p in parts[:2])  # int keys: checked below
        try:
            num = int(parts[2])
        except ValueError:
            raise SweepError(f"--vary {key}: NUM must be a whole number >= 1, got {parts[2].strip()!r}") from None
        if num < 1:
            raise SweepError(f"--vary {key}: NUM must be >= 1, got {num}")
        values = [float(x) for x in np.linspace(start, stop, num)]
        if num == 1:
            values = [start]
        if decl.kind == "int":  # linspace's round-off (30.000000000000004) is not a fraction
            values = [float(round(x)) if abs(x - round(x)) <= 1e-9 * max(1.0, abs(x)) else x for x in values]
            bad = [x for x in values if not float(x).is_integer()]
            if bad:
                raise SweepError(f"--vary {key}: is a whole number, but {rhs} gives {_fmt(bad[0])}")
            values = [int(x) for x in values]
    else:
        items = [v.strip() for v in rhs.split(",")]
        if any(not v for v in items):
            raise SweepError(f"--vary {key}: empty value in {rhs!r}")
        values = items if decl.kind == "str" else [_number(v, decl, key) for v in items]
    if len(set(values)) != len(values):
        raise SweepError(f"--vary {key}: a value is repeated in {rhs!r}")
    return Vary(key, path, decl, values)


class _Float:
    kind = "float"


_FLOAT = _Float()


def _fmt(v):
    """A value as the CSV writes it (and as a re-run recognises it): repr of floats (round-trips)."""
    if isinstance(v, float):
        return repr(v)
    return str(v)


# ---------------------------------------------------------------------------
# TOML out


# ---------------------------------------------------------------------------
# points


def point_texts(text, varies, source=None):
    """Every point of the sweep: ``[(values tuple, TOML text), ...]`` in product order, each validated.

    Raises ``SweepError`` (bad key for this scene) or :class:`~varint.SceneError` (an invalid point), naming
    the point and its key values, before anything runs.
    """
    from .scene.schema import parse_scene

    base = tomllib.loads(text)
    out = []
    for i, values in enumerate(itertools.product(*(v.values for v in varies))):
        doc = _copy(base)
        where = ", ".join(f"{v.key} = {_fmt(x)}" for v, x in zip(varies, values))
        try:
            for v, x in zip(varies, values):
                set_key(doc, v.path, x)
        except KeyPathError as exc:
            raise SweepError(f"{source + ': ' if source else ''}{exc}") from None
        t = to_toml(doc)
        try:
            parse_scene(t)
        except SceneError as exc:
            raise SceneError([f"sweep point {i} ({where}): {p}" for p in exc.problems], source=source) from None
        out.append((values, t))
    return out


def point_numbers(idents, kept):
    """The number (``point`` column, run file ``point_NNNN.h5``) of each point not in ``kept``.

    ``idents``: the points' key values as the table writes them, in product order; ``kept``: the
    finished rows' ``{ident: point number}``.  A point's number is its place in the product, unless a
    kept row (of an earlier, different sweep in the directory) has it: then the next number no row
    uses.  So an interrupted sweep, continued, numbers its points as it would have uninterrupted.
    """
    used = {int(n) for n in kept.values() if str(n).isdigit()}
    spare = max(used, default=-1) + 1
    out = {}
    for i, ident in enumerate(idents):
        if ident in kept:
            continue
        if i in used:
            while spare in used:
                spare += 1
            i = spare
        used.add(i)
        out[ident] = i
    return out


def _copy(x):
    if isinstance(x, dict):
        return {k: _copy(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_copy(v) for v in x]
    return x


def compute_point(text, analysis, out=None, count=20, about="initial"):
    """One point (runs on a Dask worker): ``{"status": "ok", results...}`` or ``{"status": "failed", "error": line}``.

    A :class:`~varint.VarintError` is the point's failure; any other exception is a bug in varint or a lost
    worker, recorded as status "crashed" (retried by a re-run).
    """
    from .scene.schema import parse_scene

    try:
        with np.errstate(all="ignore"):  # as the CLI: Newton's excursions fail with one line, not warnings
            scene = parse_scene(text)
            if analysis == "modes":
                from .analysis.modes import scene_modes, strongest

                return {"status": "ok", **strongest(scene_modes(scene, count=count, about=about)["modes"])}
            from .run.io import read_run, summary
            from .run.runner import run_scene

            if out is not None and os.path.exists(out):
                os.remove(out)  # left by an unfinished attempt (finished points are never computed again)
            run_scene(scene, out, progress=False)
            return {"status": "ok", **_run_results(read_run(out), summary(out))}
    except VarintError as exc:
        return {"status": "failed", "error": " | ".join(str(exc).splitlines())}
    except Exception as exc:  # noqa: BLE001 - recorded, so that one point does not stop the sweep
        return {"status": "crashed", "error": f"{type(exc).__name__}: {' | '.join(str(exc).splitlines())}"}


def _run_results(run, summ):
    """The final scalar monitors of a run, then the summary's deviations (``varint info``)."""
    res = {"t_end": float(run["time"][-1]), "records": int(len(run["time"]))}
    for name in sorted(run["monitors"]):
        v = run["monitors"][name]
        if v.ndim == 1 and len(v):
            x = v[-1].item()
            res[name] = x
    for k, v in summ.items():
        if isinstance(v, (int, float)) and not isinstance(v, bool) and k not in ("records", "step"):
            res[k] = v
    return res


# ---------------------------------------------------------------------------
# the table


def _read_table(path):
    if not path.exists():
        return [], []
    try:
        with open(path, newline="", encoding="utf-8") as f:
            r = csv.DictReader(f)
            rows = list(r)
            return list(r.fieldnames or []), rows
    except (OSError, csv.Error, UnicodeDecodeError) as exc:
        raise OutputError(f"{path}: cannot read the sweep table ({exc})") from None


def finished_points(out_dir):
    """How many points ``DIR/sweep.csv`` holds as finished (ok or failed); 0 when it cannot be read."""
    try:
        _, rows = _read_table(Path(out_dir) / "sweep.csv")
    except VarintError:
        return 0
    return sum(r.get("status") in ("ok", "failed") for r in rows)


def _write_table(path, columns, rows):
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=columns, extrasaction="ignore")
        w.writeheader()
        for row in rows:
            w.writerow({k: ("" if row.get(k) is None else _cell(row.get(k))) for k in columns})
    os.replace(tmp, path)


def _cell(v):
    if isinstance(v, float):
        return repr(v)
    return v


def _columns(keys, analysis, rows, old):
    result = list(MODES_COLUMNS) if analysis == "modes" else []
    for c in old:
        if c not in keys and c not in TAIL_COLUMNS and c not in result:
            result.append(c)
    for row in rows:
        for c in row:
            if c not in keys and c not in TAIL_COLUMNS and c not in result:
                result.append(c)
    tail = [c for c in TAIL_COLUMNS if not (c == "file" and analysis == "modes")]
    return list(keys) + result + tail


# ---------------------------------------------------------------------------
# the sweep


def _client(scheduler, workers):
    """A ``(client, cluster)`` pair: a local cluster of ``workers`` single-threaded processes, or ``scheduler``'s."""
    import logging

    from distributed import Client, LocalCluster

    # the scheduler's and nannies' INFO lines (start, register, close) are not the user's business
    for name in ["distributed", *logging.root.manager.loggerDict]:
        if name.startswith("distributed"):
            logging.getLogger(name).setLevel(logging.ERROR)
    if scheduler is not None:
        try:
            return Client(scheduler, timeout="20s"), None
        except (OSError, TimeoutError, ValueError) as exc:
            raise SweepError(f"--scheduler {scheduler}: cannot connect ({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})") from None
    # no dashboard; its HTTP server (health checks) on a free port, never 8787 (another cluster's)
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, silence_logs=logging.ERROR,
                           dashboard_address=":0", scheduler_kwargs={"dashboard": False})
    return Client(cluster), cluster


def _quiet_close(client, cluster):
    """Close the client and a local cluster.  A worker's connection closing under load during the shutdown is
    logged by distributed at ERROR level with a CommClosedError traceback, though every point is done and
    recorded: the user's stderr is not the place for it, so the distributed loggers are raised to CRITICAL for the
    shutdown only."""
    import logging

    names = [n for n in ["distributed", *logging.root.manager.loggerDict] if n.startswith("distributed")]
    levels = {n: logging.getLogger(n).level for n in names}
    try:
        for n in names:
            logging.getLogger(n).setLevel(logging.CRITICAL)
        client.close()
        if cluster is not None:
            cluster.close()
    finally:
        for n, level in levels.items():
            logging.getLogger(n).setLevel(level)


def sweep(scene_path, vary_specs, analysis, out_dir, scheduler=None, workers=None, count=20, about="initial",
          progress=None):
    """Run a sweep; returns a summary dict (``table``, ``points``, ``computed``, ``skipped``, ``ok``, ``failed``, ``crashed``).

    Raises :class:`~varint.VarintError` (one line per problem) before anything runs when a --vary, a point
    or the output directory is wrong.
    """
    from .scene.schema import load_scene

    if analysis not in ANALYSES:
        raise SweepError(f"--analysis: choose one of {', '.join(ANALYSES)}, got {analysis!r}")
    if not vary_specs:
        raise SweepError("give at least one --vary KEY=START:STOP:NUM or KEY=V1,V2,...")
    if workers is not None and workers < 1:
        raise SweepError(f"--workers must be >= 1, got {workers}")
    if workers is not None and scheduler is not None:
        raise SweepError("--workers sizes a local cluster; with --scheduler the cluster has its own workers")
    if count < 1:
        raise SweepError(f"-n/--count must be >= 1, got {count}")
    scene = load_scene(scene_path)
    varies = [parse_vary(s) for s in vary_specs]
    keys = [v.key for v in varies]
    dup = [k for k in keys if keys.count(k) > 1]
    if dup:
        raise SweepError(f"--vary {dup[0]}: given twice")
    points = point_texts(scene.text, varies, source=str(scene_path))

    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise OutputError(f"{out}: is not a directory")
    if not out.parent.is_dir():
        raise OutputError(f"{out}: directory {out.parent} does not exist")
    table = out / "sweep.csv"
    meta_path = out / "sweep.json"
    meta = {"scene": str(scene_path), "scene_toml": scene.text, "analysis": analysis, "keys": keys}
    if analysis == "modes":
        meta.update(count=count, about=about)
    old_cols, old_rows = _read_table(table)
    if meta_path.exists() or old_rows:
        try:
            old_meta = json.loads(meta_path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            raise OutputError(f"{out}: has a sweep.csv without a readable sweep.json; use another --out directory") from None
        for what, name in (("scene_toml", "scene (its text differs)"), ("analysis", "--analysis"), ("keys", "--vary keys"),
                           ("count", "-n/--count"), ("about", "--about")):
            if old_meta.get(what) != meta.get(what):
                raise OutputError(f"{out}: holds a sweep with another {name}: {old_meta.get(what) if what != 'scene_toml' else old_meta.get('scene')!r}; "
                                  "use another --out directory")
    # finished points (ok or failed) are kept and skipped; crashed ones are computed again
    kept = {}
    for row in old_rows:
        ident = tuple(row.get(k, "") for k in keys)
        if row.get("status") in ("ok", "failed"):
            kept[ident] = row
    rows = dict(kept)
    idents = [tuple(_fmt(x) for x in values) for values, _ in points]
    numbers = point_numbers(idents, {k: r.get("point", "") for k, r in kept.items()})
    todo = [(numbers[ident], ident, values, text) for ident, (values, text) in zip(idents, points) if ident not in kept]
    out.mkdir(exist_ok=True)
    meta_path.write_text(json.dumps(meta, indent=1), encoding="utf-8")
    result = {"table": str(table), "points": len(points), "skipped": len(points) - len(todo), "computed": len(todo)}

    def save():
        cols = _columns(keys, analysis, rows.values(), old_cols)
        order = sorted(rows.values(), key=lambda r: int(r["point"]) if str(r.get("point", "")).isdigit() else 1 << 30)
        _write_table(table, cols, order)

    if todo:
        from tqdm import tqdm

        client, cluster = _client(scheduler, workers)
        try:
            futures = {}
            for number, ident, values, text in todo:
                f = out / f"point_{number:04d}.h5" if analysis == "run" else None
                # an absolute path: the workers of an existing cluster need not share this working directory
                fut = client.submit(compute_point, text, analysis, str(f.resolve()) if f else None, count, about, pure=False)
                futures[fut] = (number, ident, f)
            from distributed import as_completed

            bar = tqdm(total=len(todo), unit="point", desc="sweep", file=sys.stderr,
                       disable=not (sys.stderr.isatty() if progress is None else progress))
            try:
                for fut in as_completed(futures):
                    number, ident, f = futures[fut]
                    try:
                        res = fut.result()
                    except Exception as exc:  # noqa: BLE001 - a lost worker: the point is retried by a re-run
                        res = {"status": "crashed", "error": f"{type(exc).__name__}: {' | '.join(str(exc).splitlines())}"}
                    row = dict(zip(keys, ident))
                    row.update(res)
                    row["point"] = number
                    if f is not None and f.exists():  # a failed run keeps the records before its failure
                        row["file"] = f.name
                    rows[ident] = row
                    save()
                    bar.update(1)
            finally:
                bar.close()
        finally:
            _quiet_close(client, cluster)
    else:
        save()
    st = [r.get("status") for r in rows.values()]
    result.update(ok=st.count("ok"), failed=st.count("failed"), crashed=st.count("crashed"))
    return result
