"""HDF5 run files (DESIGN §5), written incrementally and resumable.

Layout::

    /                      attrs: varint_version, scene_toml, scheme, step, title, records
    /time                  (K,)  dimension scale "time"
    /monitors/<name>       (K, ...)
    /fields/<group>/<name> (K, ...)
    /checkpoint            q, p, lam, v, q_prev + attrs n, t, records

Each record is appended (datasets resized by one), then the checkpoint is
overwritten and ``records`` incremented, then the file is flushed.  A run
killed at any point leaves the last flushed state readable; ``--resume`` trims
anything past ``records`` and continues from the checkpoint.
"""

from __future__ import annotations

import h5py
import numpy as np

from . import __version__
from .errors import OutputError
from .stepper import State

__all__ = ["RunWriter", "read_run", "read_checkpoint", "summary"]


class RunWriter:
    """Append-only writer of one run file."""

    def __init__(self, path, scene, h, monitors, fields, resume=False):
        self.path = str(path)
        try:
            if resume:
                self.f = h5py.File(self.path, "r+")
                self._check_resumable(scene)
                self._trim()
            else:
                self.f = h5py.File(self.path, "w")
                self._create(scene, h, monitors, fields)
        except OSError as exc:
            raise OutputError(f"{self.path}: cannot {'resume' if resume else 'create'} the run file ({_oserr(exc)})") from None

    # -- creation ----------------------------------------------------------------

    def _create(self, scene, h, monitors, fields):
        f = self.f
        f.attrs["varint_version"] = __version__
        f.attrs["scene_toml"] = scene.text
        f.attrs["scheme"] = scene.time.scheme
        f.attrs["step"] = float(h)
        f.attrs["title"] = scene.title
        f.attrs["records"] = 0
        t = f.create_dataset("time", shape=(0,), maxshape=(None,), dtype="f8", chunks=(256,))
        t.attrs["units"] = "s"
        t.make_scale("time")
        for name, val in monitors.items():
            self._series(f"monitors/{name}", np.asarray(val))
        for name, val in fields.items():
            self._series(f"fields/{name}", np.asarray(val))
        cp = f.create_group("checkpoint")
        cp.attrs["n"] = 0
        cp.attrs["t"] = 0.0
        cp.attrs["records"] = 0
        self.f.flush()

    def _series(self, path, val):
        shape = val.shape
        nbytes = max(val.nbytes, 8)
        rows = int(max(1, min(1024, (1 << 20) // nbytes)))
        d = self.f.create_dataset(path, shape=(0,) + shape, maxshape=(None,) + shape,
                                  dtype="f8" if val.dtype.kind == "f" else "i8", chunks=(rows,) + shape)
        d.dims[0].attach_scale(self.f["time"])
        d.dims[0].label = "time"

    # -- resume ------------------------------------------------------------------

    def _check_resumable(self, scene):
        f = self.f
        if "checkpoint" not in f or "scene_toml" not in f.attrs:
            raise OutputError(f"{self.path}: not a varint run file (no checkpoint); cannot resume")
        if f.attrs["scene_toml"] != scene.text:
            raise OutputError(f"{self.path}: was started from a different scene; resume with the same scene file")

    def _trim(self):
        k = int(_active_checkpoint(self.f).attrs["records"])
        for d in self._datasets():
            if d.shape[0] != k:
                d.resize(k, axis=0)
        self.f.attrs["records"] = k

    def _datasets(self):
        out = [self.f["time"]]
        self.f.visititems(lambda name, obj: out.append(obj) if isinstance(obj, h5py.Dataset) and (
            name.startswith("monitors/") or name.startswith("fields/")) else None)
        return out

    def checkpoint_state(self):
        return read_checkpoint(self.f)

    # -- writing -----------------------------------------------------------------

    def append(self, t, monitors, fields, state):
        f = self.f
        k = int(f.attrs["records"])
        try:
            self._put(f["time"], k, t)
            for name, val in monitors.items():
                self._put(f[f"monitors/{name}"], k, val)
            for name, val in fields.items():
                self._put(f[f"fields/{name}"], k, val)
            # The restart state goes to the slot *not* in use, is flushed, and only then does the
            # pointer move: a run killed mid-write (SIGKILL, no chance to clean up) still finds a
            # consistent state under the old pointer.  (Overwriting a single slot in place let the raw
            # state reach the file before its step counter: a resume then restarted one record late.)
            cp = f["checkpoint"]
            slot = "b" if cp.attrs.get("slot", "") == "a" else "a"
            g = cp.require_group(slot)
            for name in ("q", "p", "lam", "v", "q_prev"):
                val = getattr(state, name)
                if val is None:
                    if name in g:
                        del g[name]
                    continue
                if name in g and g[name].shape == val.shape:
                    g[name][...] = val
                else:
                    if name in g:
                        del g[name]
                    g.create_dataset(name, data=val)
            g.attrs["n"] = state.n
            g.attrs["t"] = state.t
            g.attrs["records"] = k + 1
            f.flush()
            cp.attrs["slot"] = slot
            cp.attrs["n"] = state.n
            cp.attrs["t"] = state.t
            cp.attrs["records"] = k + 1
            f.attrs["records"] = k + 1
            f.flush()
        except OSError as exc:
            raise OutputError(f"{self.path}: write failed ({_oserr(exc)})") from None

    @staticmethod
    def _put(d, k, val):
        if d.shape[0] <= k:
            d.resize(k + 1, axis=0)
        d[k] = val

    def close(self):
        try:
            self.f.close()
        except Exception:  # noqa: BLE001 - closing after a failed write must not mask the first error
            pass


def _oserr(exc):
    return str(exc).split("(")[0].strip() or exc.__class__.__name__


def _active_checkpoint(f):
    """The checkpoint slot in use; files written before the two slots kept the state in /checkpoint itself."""
    cp = f["checkpoint"]
    slot = cp.attrs.get("slot", "")
    return cp[slot] if slot else cp


def read_checkpoint(f):
    src = _active_checkpoint(f)
    if "q" not in src:
        raise OutputError("the run file has no checkpoint yet; start the run again without --resume")
    get = lambda n: src[n][...] if n in src else None  # noqa: E731
    return State(int(src.attrs["n"]), float(src.attrs["t"]), get("q"), get("p"), get("lam"), get("v"), get("q_prev"))


def read_run(path):
    """Load a run file into plain arrays: ``{"time", "monitors": {...}, "fields": {...}, "attrs": {...}}``."""
    try:
        with h5py.File(path, "r") as f:
            k = int(f.attrs.get("records", f["time"].shape[0]))
            out = {"attrs": {a: _attr(f.attrs[a]) for a in f.attrs}, "time": f["time"][:k], "monitors": {}, "fields": {}}
            for name, d in f["monitors"].items():
                out["monitors"][name] = d[:k]
            for g in f["fields"]:
                for name, d in f["fields"][g].items():
                    out["fields"][f"{g}/{name}"] = d[:k]
            return out
    except (OSError, KeyError) as exc:
        raise OutputError(f"{path}: not a readable varint run file ({_oserr(exc)})") from None


def _attr(v):
    return v.item() if isinstance(v, np.generic) else v


def summary(path):
    """Short description of a run file for ``varint info``."""
    run = read_run(path)
    mon = run["monitors"]
    d = {
        "file": str(path),
        "title": run["attrs"].get("title"),
        "varint_version": run["attrs"].get("varint_version"),
        "scheme": run["attrs"].get("scheme"),
        "step": run["attrs"].get("step"),
        "records": int(len(run["time"])),
        "time": [float(run["time"][0]), float(run["time"][-1])] if len(run["time"]) else [],
        "monitors": sorted(mon),
        "fields": {k: list(v.shape) for k, v in run["fields"].items()},
    }
    if len(run["time"]) and "energy" in mon:
        E = mon["energy"]
        # relative to |E(0)|, or to the largest kinetic energy when the run starts at zero energy
        ref = max(abs(E[0]), float(np.max(mon["kinetic_energy"])) if "kinetic_energy" in mon else 0.0, 1e-300)
        d["energy_relative_deviation"] = float(np.max(np.abs(E - E[0])) / ref)
        d["mass_relative_deviation"] = float(np.max(np.abs(mon["mass"] - mon["mass"][0])) / max(abs(mon["mass"][0]), 1e-300)) if "mass" in mon else None
        d["newton_iterations_max"] = int(np.max(mon["newton_iterations"])) if "newton_iterations" in mon else None
        if "angular_momentum_cm" in mon:  # rods: the momenta (reactions of supports included) and the frames
            for key in ("linear_momentum", "angular_momentum_cm"):
                v = mon[key]
                d[f"{key}_deviation"] = float(np.max(np.linalg.norm(v - v[0], axis=1)))
            d["frame_orthogonality_max"] = float(np.max(mon["frame_orthogonality"]))
    return d
