"""HDF5 run files, written incrementally and resumable (layout: docs/output.md).

Layout::

    /                      attrs: varint_version, scene_toml, scheme, step, title, records, invariants,
                           status (running | finished | failed | interrupted) [+ status_step, status_time,
                           status_message, status_resumable]
    /time                  (K,)  dimension scale "time", hard-linked into every group of series
    /parcel, /label, /node, /component, /axis
                           netCDF dimensions without values (empty dimension scales)
    /monitors/<name>       (K, ...)
    /fields/<group>/<name> (K, ...)
    /checkpoint            slots a, b with q, p, lam, v, q_prev + attrs slot, n, t, records

Every axis of every dataset carries an HDF5 dimension scale and every dataset a ``units``
attribute, so netCDF readers (xarray with ``engine="h5netcdf"``) open the file group by group.
The scales of the index axes live at the root: netCDF looks a dimension up in a variable's
group and its ancestors.

Each record is appended (datasets resized by one), then the checkpoint is
overwritten and ``records`` incremented, then the file is flushed.  A run
killed at any point leaves the last flushed state readable; ``--resume`` trims
anything past ``records`` and continues from the checkpoint.  Chunks hold at most 64 kB and no
more records than the run will write, so a short run's file is about the size of its data.
"""

from __future__ import annotations

import os

import h5py
import numpy as np

from ..version import __version__
from ..errors import OutputError
from ..schemes.state import State

__all__ = ["RunWriter", "read_run", "read_checkpoint", "check_resumable", "summary", "UNITS", "DIMS", "units_of",
           "energy_motion_scale"]

#: Units of every dataset (UDUNITS spelling, "1" for dimensionless), by path in the file.
UNITS = {
    "time": "s",
    # monitors
    "monitors/energy": "J",
    "monitors/kinetic_energy": "J",
    "monitors/energy_fluid_kinetic": "J",
    "monitors/energy_wall_kinetic": "J",
    "monitors/energy_internal": "J",
    "monitors/energy_wall_elastic": "J",
    "monitors/energy_external_pressure": "J",
    "monitors/energy_gravity": "J",
    "monitors/energy_bending_torsion": "J",
    "monitors/energy_stretch_shear": "J",
    "monitors/energy_load": "J",
    "monitors/external_work": "J",
    "monitors/mass": "kg",
    "monitors/linear_momentum": "kg m/s",
    "monitors/angular_momentum": "kg m^2/s",
    "monitors/angular_momentum_cm": "kg m^2/s",
    "monitors/entropy": "J/K",
    "monitors/constraint_residual": "1",
    "monitors/rod_constraint_residual": "1",
    "monitors/newton_iterations": "1",
    "monitors/halved_steps": "1",
    "monitors/frame_orthogonality": "1",
    # open ends (docs/theory.md §13.4): what crossed the ends since t = 0, and the balances
    "monitors/energy_flux": "J",
    "monitors/momentum_flux": "kg m/s",
    "monitors/mass_flux": "kg",
    "monitors/energy_balance": "J",
    "monitors/momentum_balance": "kg m/s",
    "monitors/mass_balance": "kg",
    "monitors/parcels": "1",
    "monitors/support_impulse": "kg m/s",
    # fields
    "fields/fluid/s": "m",
    "fields/fluid/position": "m",
    "fields/fluid/density": "kg/m^3",
    "fields/fluid/pressure": "Pa",
    "fields/fluid/velocity": "m/s",
    "fields/fluid/entropy": "J/(kg K)",
    "fields/fluid/active": "1",
    "fields/wall/R": "m",
    "fields/wall/velocity": "m/s",
    "fields/rod/r": "m",
    "fields/rod/Lambda": "1",
}

#: Names of the axes after the first (time), by path; monitors of shape (3,) are vectors ("component").
DIMS = {
    "fields/fluid/s": ("label",),
    "fields/fluid/position": ("label", "component"),
    "fields/fluid/velocity": ("label",),
    "fields/fluid/density": ("parcel",),
    "fields/fluid/pressure": ("parcel",),
    "fields/fluid/entropy": ("parcel",),
    "fields/fluid/active": ("label",),
    "fields/wall/R": ("node",),
    "fields/wall/velocity": ("node",),
    "fields/rod/r": ("node", "component"),
    "fields/rod/Lambda": ("node", "component", "axis"),  # column j: body axis E_j in space
}

_DIMENSIONS = {
    "parcel": "parcel index k (between labels k and k+1)",
    "label": "label index (parcel boundaries)",
    "node": "node index",
    "component": "spatial component (x, y, z)",
    "axis": "body axis E_1, E_2, E_3 (columns of Lambda)",
}

#: What the packed restart vectors hold (their entries have the SI unit of their own kind).
_CHECKPOINT = {
    "q": "generalised coordinates at the level",
    "p": "discrete momenta at the level",
    "lam": "algebraic unknowns (multipliers, quasistatic radii) of the last step",
    "v": "velocities of the last step",
    "q_prev": "generalised coordinates at the previous level",
}


def units_of(path):
    """Units of the dataset at ``path`` (e.g. ``"fields/fluid/pressure"``), or None if not tabulated."""
    path = path.lstrip("/")
    if path in UNITS:
        return UNITS[path]
    if path.startswith("monitors/energy_"):  # every energy term
        return "J"
    return None


def _dims_of(path, shape):
    """Names of the axes of a series after time (known paths from DIMS, else generic ones)."""
    path = path.lstrip("/")
    names = DIMS.get(path)
    if names is not None and len(names) == len(shape):
        return names
    if path.startswith("monitors/") and shape == (3,):
        return ("component",)
    stem = path.replace("/", "_")
    return tuple(f"{stem}_dim{i + 1}" for i in range(len(shape)))


_NOT_A_VARIABLE = "This is a netCDF dimension but not a netCDF variable."


def _make_dimension(g, name, size, description=None):
    """A netCDF dimension without coordinate values: an empty dimension scale (no storage is allocated)."""
    d = g.create_dataset(name, shape=(size,), dtype="f4")
    d.make_scale(f"{_NOT_A_VARIABLE}{size:10d}")
    d.attrs["units"] = "1"
    if description:
        d.attrs["long_name"] = description
    return d


def _root_dimension(f, name, size):
    """The root dimension ``name`` of length ``size`` (a clash of sizes gets ``name_size``)."""
    if name in f:
        d = f[name]
        if isinstance(d, h5py.Dataset) and d.shape == (size,) and d.is_scale:
            return d
        return _root_dimension(f, f"{name}_{size}", size)
    return _make_dimension(f, name, size, _DIMENSIONS.get(name))


def _series_of(f):
    """Every series (time-indexed dataset) under /monitors and /fields, scales left out."""
    out = []
    for top in ("monitors", "fields"):
        if top in f:
            f[top].visititems(lambda name, obj: out.append(obj) if isinstance(obj, h5py.Dataset) and not obj.is_scale else None)
    return out


def _label_file(f):
    """Label every axis of every series with a dimension scale and give it its units (idempotent: old
    files get the same on resume).  /time is also linked into each group of series (a hard link, not a
    copy), so a group opened on its own has its time coordinate."""
    for d in _series_of(f):
        path = d.name.lstrip("/")
        names = ("time",) + _dims_of(path, d.shape[1:])
        for axis, name in enumerate(names):
            if not len(d.dims[axis]):
                d.dims[axis].attach_scale(f["time"] if axis == 0 else _root_dimension(f, name, d.shape[axis]))
        if "units" not in d.attrs and units_of(path) is not None:
            d.attrs["units"] = units_of(path)
        group = d.parent
        if "time" not in group:
            group["time"] = f["time"]


def _put_vector(g, name, val):
    """Write a restart vector into checkpoint slot ``g`` with its own index dimension ``<name>_index``."""
    dim = f"{name}_index"
    if name in g and g[name].shape == val.shape and dim in g and len(g[name].dims[0]):
        g[name][...] = val
        return
    for k in (name, dim):
        if k in g:
            del g[k]
    d = g.create_dataset(name, data=val)
    d.dims[0].attach_scale(_make_dimension(g, dim, val.shape[0], f"index of {name}"))
    d.attrs["units"] = "SI"  # a packed vector: each entry in the SI unit of its own kind
    d.attrs["long_name"] = _CHECKPOINT.get(name, name)


class RunWriter:
    """Append-only writer of one run file."""

    def __init__(self, path, scene, h, monitors, fields, resume=False, records=None, invariants=None, scheme=None):
        self.path = str(path)
        self.f = None
        self.scheme = scheme or scene.time.scheme  # the scheme that steps the run ("auto" resolved by the caller)
        self.records = records
        self.invariants = invariants
        try:
            if resume:
                self.f = h5py.File(self.path, "r+")
                self._check_resumable(scene)
                self._trim()
                self._upgrade()
                self.set_status("running")
            else:
                self.f = h5py.File(self.path, "w")
                self._create(scene, h, monitors, fields)
        except OSError as exc:
            self._abandon(resume)
            raise OutputError(f"{self.path}: cannot {'resume' if resume else 'create'} the run file ({_oserr(exc)})") from None
        except BaseException:
            self._abandon(resume)
            raise

    def _abandon(self, resume):
        """Close after a failed start; a file this writer created (and could not finish creating) is removed, so that
        no half-made file is left that neither ``info`` can read nor a rerun may replace without --force."""
        created = not resume and self.f is not None
        self.close()
        if created:
            try:
                os.unlink(self.path)
            except OSError:
                pass

    # -- creation ----------------------------------------------------------------

    def _create(self, scene, h, monitors, fields):
        f = self.f
        f.attrs["varint_version"] = __version__
        f.attrs["scene_toml"] = scene.text
        f.attrs["scheme"] = self.scheme
        f.attrs["step"] = float(h)
        f.attrs["title"] = scene.title
        f.attrs["records"] = 0
        f.attrs["status"] = "running"
        if self.invariants is not None:  # what the model declares (varint info prints their deviations only)
            f.attrs["invariants"] = ",".join(self.invariants)
        t = f.create_dataset("time", shape=(0,), maxshape=(None,), dtype="f8", chunks=(self._rows(8),))
        t.attrs["units"] = "s"
        t.make_scale("time")
        t.attrs["long_name"] = "time"
        f.require_group("monitors")
        f.require_group("fields")  # present even when output.fields = [] selects no group
        for name, val in monitors.items():
            self._series(f"monitors/{name}", np.asarray(val))
        for name, val in fields.items():
            self._series(f"fields/{name}", np.asarray(val))
        _label_file(f)
        cp = f.create_group("checkpoint")
        cp.attrs["n"] = 0
        cp.attrs["t"] = 0.0
        cp.attrs["records"] = 0
        self.f.flush()

    #: The largest chunk of a series in bytes.  HDF5 allocates a chunk whole as soon as one record lands in it, so a
    #: chunk must not be much larger than the data (a 10-record file of 1 MB chunks was 1.4 MB for 20 kB of data).
    CHUNK_BYTES = 64 * 1024

    def _rows(self, nbytes):
        """Records per chunk of a series whose record has ``nbytes``: as many as fit in CHUNK_BYTES (at most 1024,
        at least 1), and no more than the run will write (``records``), so a short run's file is the size of its data."""
        rows = max(1, min(1024, self.CHUNK_BYTES // max(int(nbytes), 1)))
        if self.records:
            rows = min(rows, int(self.records))
        return rows

    def _series(self, path, val):
        shape = val.shape
        d = self.f.create_dataset(path, shape=(0,) + shape, maxshape=(None,) + shape,
                                  dtype="f8" if val.dtype.kind == "f" else "i8", chunks=(self._rows(8 * max(val.size, 1)),) + shape)
        d.dims[0].attach_scale(self.f["time"])
        return d

    # -- resume ------------------------------------------------------------------

    def _check_resumable(self, scene):
        _refuse_resume(self.f, self.path, scene)

    # -- status ------------------------------------------------------------------

    def set_status(self, status, step=None, time=None, message=None, resumable=None):
        """Say in the root attributes how the run goes (docs/output.md): ``status`` (running, finished, failed,
        interrupted), with ``status_step``, ``status_time``, ``status_message`` where it ended otherwise than
        finished; ``status_resumable`` whether ``--resume`` continues a failed run (only a failure to write the file:
        a step that failed would fail again the same way).  A file that cannot take the attributes any more (a full
        disk) keeps its last status: ``running``."""
        if self.f is None:
            return
        try:
            a = self.f.attrs
            a["status"] = status
            for k in ("status_step", "status_time", "status_message", "status_resumable"):
                if k in a:
                    del a[k]
            if status != "running":
                if step is not None:
                    a["status_step"] = int(step)
                if time is not None:
                    a["status_time"] = float(time)
                if message:
                    a["status_message"] = str(message)
                if status == "failed":
                    a["status_resumable"] = bool(resumable)
            self.f.flush()
        except (OSError, ValueError, RuntimeError, KeyError):
            pass

    def _upgrade(self):
        """Files written before the dimension scales get them (and units) when resumed."""
        if not self.f["time"].is_scale:
            self.f["time"].make_scale("time")
        if "units" not in self.f["time"].attrs:
            self.f["time"].attrs["units"] = "s"
        _label_file(self.f)

    def _trim(self):
        k = int(_active_checkpoint(self.f).attrs["records"])
        for d in self._datasets():
            if d.shape[0] != k:
                d.resize(k, axis=0)
        self.f.attrs["records"] = k

    def _datasets(self):
        return [self.f["time"]] + _series_of(self.f)

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
                    for stale in (name, f"{name}_index"):
                        if stale in g:
                            del g[stale]
                    continue
                _put_vector(g, name, np.asarray(val))
            for name in [k for k in g if k.startswith("data_") and not k.endswith("_index")]:
                if not state.data or name[5:] not in state.data:
                    del g[name]
                    if f"{name}_index" in g:
                        del g[f"{name}_index"]
            for name, val in (state.data or {}).items():  # what forces change as the run goes (State.data)
                _put_vector(g, f"data_{name}", np.asarray(val))
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
            if self.f is not None:
                self.f.close()
        except Exception:  # noqa: BLE001 - closing after a failed write must not mask the first error
            pass


def _refuse_resume(f, path, scene):
    """Raise OutputError (one line) when the open run file ``f`` cannot be continued with ``scene``."""
    if "checkpoint" not in f or "scene_toml" not in f.attrs:
        raise OutputError(f"{path}: not a varint run file (no checkpoint); cannot resume")
    if f.attrs.get("static", False):
        raise OutputError(f"{path}: holds a static equilibrium written by `varint static`, not a run; "
                          "it cannot be resumed (run the scene into another file)")
    if f.attrs["scene_toml"] != scene.text:
        raise OutputError(f"{path}: was started from a different scene; resume with the same scene file")
    if _attr(f.attrs.get("status")) == "failed" and not f.attrs.get("status_resumable", False):
        raise OutputError(f"{path}: the run failed at step {_attr(f.attrs.get('status_step', '?'))} "
                          f"(t = {float(f.attrs.get('status_time', float('nan'))):.6g} s) and a resume would repeat the same "
                          "steps: it cannot be resumed; change the scene (e.g. a smaller time.step) and run it into another file")


def check_resumable(path, scene):
    """Raise OutputError (one line) unless ``path`` is a run of ``scene`` that ``--resume`` can continue: not a static
    file, not another scene's run, not a run that failed in a step (docs/output.md, "Status").  Read only."""
    try:
        with h5py.File(path, "r") as f:
            _refuse_resume(f, path, scene)
    except OSError as exc:
        raise OutputError(f"{path}: cannot resume the run file ({_oserr(exc)})") from None


def _oserr(exc):
    """The reason of an h5py OSError in words (not HDF5's "Unable to synchronously ..." wording)."""
    msg = str(exc)
    if "unable to lock file" in msg:
        return "the file is open in another process"
    if "file signature not found" in msg:
        return "not an HDF5 file"
    if getattr(exc, "errno", None):
        return os.strerror(exc.errno)
    inner = msg[msg.find("(") + 1:msg.rfind(")")] if "(" in msg else msg
    return inner.split(",")[0].strip() or exc.__class__.__name__


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
    data = {k[5:]: src[k][...] for k in src if k.startswith("data_") and not k.endswith("_index")} or None
    return State(int(src.attrs["n"]), float(src.attrs["t"]), get("q"), get("p"), get("lam"), get("v"), get("q_prev"), data)


def read_run(path):
    """Load a run file into plain arrays: ``{"time", "monitors": {...}, "fields": {...}, "attrs": {...}}``."""
    try:
        with h5py.File(path, "r") as f:
            k = int(f.attrs.get("records", f["time"].shape[0]))
            out = {"attrs": {a: _attr(f.attrs[a]) for a in f.attrs}, "time": f["time"][:k], "monitors": {}, "fields": {}}
            for name, d in f["monitors"].items():
                if not d.is_scale:  # /monitors/time is /time
                    out["monitors"][name] = d[:k]
            for g in f.get("fields", {}):  # (files written with output.fields = [] by 0.1 have none)
                for name, d in f["fields"][g].items():
                    if not d.is_scale:
                        out["fields"][f"{g}/{name}"] = d[:k]
            return out
    except (OSError, KeyError) as exc:
        raise OutputError(f"{path}: not a readable varint run file ({_oserr(exc)})") from None


def _attr(v):
    return v.item() if isinstance(v, np.generic) else v


def _kind(attrs):
    """What the file holds, in words (``varint info``)."""
    if not attrs.get("static", False):
        return "run"
    if "flow_velocity" in attrs:
        what = f"steady flowing state (U = {float(attrs['flow_velocity']):.6g} m/s)"
    elif "steady_rotation" in attrs:
        what = "steady rotation (the shape at rest in the spinning frame)"
    else:
        what = "static equilibrium"
    return f"static: one frame written by varint static, the {what}"


def _status(attrs, records):
    """The run's status in words: how it ended, where, and why (docs/output.md, "Status")."""
    st = attrs.get("status")
    if st is None:  # written before the status existed
        return "unknown (written before varint recorded how a run ends)"
    where = ""
    if "status_step" in attrs:
        where = f" at step {int(attrs['status_step'])} (t = {float(attrs.get('status_time', float('nan'))):.6g} s)"
    if st == "finished":
        return "finished"
    if st == "running":
        return ("running, or stopped without notice (killed, a machine gone down): if no varint is writing it, "
                f"--resume continues it from its last record ({records} complete)")
    if st == "interrupted":
        return f"interrupted{where}: {attrs.get('status_message', '')}; --resume continues it"
    if st == "failed":
        tail = ("; --resume continues it once the file can be written" if attrs.get("status_resumable", False)
                else "; it cannot be resumed (a resume would repeat the failing step)")
        return f"failed{where}: {attrs.get('status_message', '?')}{tail}"
    return str(st)


def _declared_invariants(attrs):
    """The invariants the run's model declares: stored in the file (``invariants``), or, for files written before,
    derived again from the stored scene (None when that fails)."""
    if "invariants" in attrs:
        return [x for x in str(attrs["invariants"]).split(",") if x]
    try:
        from ..model.model import build_model
        from ..scene.schema import parse_scene

        with np.errstate(all="ignore"):
            return list(build_model(parse_scene(attrs["scene_toml"])).invariants())
    except Exception:  # noqa: BLE001 - an old or foreign file: no momentum deviations rather than a failure
        return None


def _gravity(attrs):
    try:
        from ..scene.schema import parse_scene

        return np.asarray(parse_scene(attrs["scene_toml"]).environment.gravity, dtype=float)
    except Exception:  # noqa: BLE001
        return np.zeros(3)


def _unit(v):
    n = float(np.linalg.norm(v))
    return np.asarray(v, dtype=float) / n if n > 0 else None


def energy_motion_scale(E, kinetic=None):
    """The energy that moves over a run, the scale of its energy error: the largest kinetic energy plus the largest
    change of the potential energy U = E - kinetic.  The internal energy of a gas at rest, a liquid's p V, the
    potential of a body far above the origin are not part of the motion, and abs(E(0)) would make any error look small
    (a water-filled hose: p V 20 J against 1.3 J of motion).  0.0 when nothing moves."""
    E = np.asarray(E, dtype=float)
    Kin = np.zeros_like(E) if kinetic is None else np.asarray(kinetic, dtype=float)
    V = E - Kin
    return float(np.max(np.abs(Kin)) + np.max(np.abs(V - V[0]))) if E.size else 0.0


def summary(path):
    """Short description of a run file for ``varint info``: what it holds, how the run ended (its status), and the
    deviations of the invariants its model declares (docs/output.md)."""
    run = read_run(path)
    attrs = run["attrs"]
    mon = run["monitors"]
    K = int(len(run["time"]))
    d = {
        "file": str(path),
        "kind": _kind(attrs),
        "status": _status(attrs, K),
        "title": attrs.get("title"),
        "varint_version": attrs.get("varint_version"),
        "scheme": attrs.get("scheme"),
        "step": attrs.get("step"),
        "records": K,
        "time": [float(run["time"][0]), float(run["time"][-1])] if K else [],
        "monitors": sorted(mon),
        "fields": {k: list(v.shape) for k, v in run["fields"].items()},
    }
    if attrs.get("status") in ("failed", "interrupted"):
        d["status_step"] = int(attrs.get("status_step", -1))
        d["status_time"] = float(attrs.get("status_time", float("nan")))
        d["status_message"] = attrs.get("status_message", "")
    if attrs.get("static", False) or K == 0:
        return d
    inv = _declared_invariants(attrs)
    if inv is not None:
        d["invariants"] = inv
    kept = (lambda name: True) if inv is None else (lambda name: name in inv)
    if "energy" in mon and (kept("energy") or "external_work" in mon):
        E = mon["energy"]
        if "external_work" in mon:  # a tip torque under the energy-momentum step: E - W is the conserved quantity
            E = E - mon["external_work"]
            d["energy_deviation_of"] = "energy - external_work"
        ref = max(energy_motion_scale(E, mon.get("kinetic_energy")), 1e-12 * float(np.max(np.abs(E))), 1e-300)
        d["energy_relative_deviation"] = float(np.max(np.abs(E - E[0])) / ref)
        d["energy_reference"] = ref
    if "mass" in mon and kept("mass"):
        d["mass_relative_deviation"] = float(np.max(np.abs(mon["mass"] - mon["mass"][0])) / max(abs(mon["mass"][0]), 1e-300))
    if "newton_iterations" in mon:
        d["newton_iterations_max"] = int(np.max(mon["newton_iterations"]))
    if "halved_steps" in mon:  # step control (docs/theory.md §4b): steps that failed at h, taken as half steps
        d["halved_steps"] = int(mon["halved_steps"][-1])
    if "energy_balance" in mon:  # open ends (docs/theory.md §13.4): the balances against the boundary fluxes
        for kind, val, flux in (("energy", mon["energy"], mon["energy_flux"]),
                                ("momentum", mon["linear_momentum"][:, 0], mon["momentum_flux"][:, 0]),
                                ("mass", mon["mass"], mon["mass_flux"])):
            b = mon[f"{kind}_balance"]
            b = b[:, 0] if b.ndim > 1 else b
            ref = max(float(np.max(np.abs(val))), float(np.max(np.abs(flux))), 1e-300)
            d[f"{kind}_balance_relative"] = float(np.max(np.abs(b)) / ref)
        d["parcels"] = [int(np.min(mon["parcels"])), int(np.max(mon["parcels"]))]
    d.update(_momentum_deviations(run, inv))
    if "frame_orthogonality" in mon:
        d["frame_orthogonality_max"] = float(np.max(mon["frame_orthogonality"]))
    return d


def _momentum_deviations(run, inv):
    """max_t |J(t) - J(0)| of each momentum (or component of one) the model declares an invariant: a clamped hose's
    linear momentum is not one (its support takes the impulse), the component across gravity of a free rod's is."""
    mon, out = run["monitors"], {}
    if "linear_momentum" not in mon or inv is None or "energy_balance" in mon:
        return out
    P, L = mon["linear_momentum"], mon.get("angular_momentum")
    dev = lambda x: float(np.max(np.abs(x - x[0]) if x.ndim == 1 else np.linalg.norm(x - x[0], axis=1)))  # noqa: E731
    g = _unit(_gravity(run["attrs"])) if any("gravity" in name for name in inv) else None
    if "linear_momentum" in inv:
        out["linear_momentum_deviation"] = dev(P)
    if "linear_momentum_transverse_to_gravity" in inv and g is not None:
        out["linear_momentum_transverse_to_gravity_deviation"] = dev(P - np.outer(P @ g, g))
    if "axial_momentum" in inv:
        out["axial_momentum_deviation"] = dev(P[:, 0])
    if L is None:
        return out
    if "angular_momentum" in inv:
        if "angular_momentum_cm" in mon:
            out["angular_momentum_cm_deviation"] = dev(mon["angular_momentum_cm"])
        else:
            out["angular_momentum_deviation"] = dev(L)
    if "angular_momentum_along_gravity" in inv and g is not None:
        out["angular_momentum_along_gravity_deviation"] = dev(L @ g)
    if "angular_momentum_along_the_period" in inv:
        out["angular_momentum_along_the_period_deviation"] = dev(L[:, 0])
    if "angular_momentum_about_the_bearing_axis" in inv and "rod/r" in run["fields"]:
        r0 = run["fields"]["rod/r"][0]
        a = _unit(r0[-1] - r0[0])
        if a is not None:  # about the pin at s = 0: L_O - r_0 x P, along the line through both pins
            out["angular_momentum_about_the_bearing_axis_deviation"] = dev((L - np.cross(r0[0], P)) @ a)
    return out
