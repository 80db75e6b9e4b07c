"""HDF5 run files, written incrementally and resumable (layout: docs/output.md).

Layout::

    /                      attrs: varint_version, scene_toml, scheme, step, title, records
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
anything past ``records`` and continues from the checkpoint.
"""

from __future__ import annotations

import os

import h5py
import numpy as np

from ..version import __version__
from ..errors import OutputError
from ..schemes.state import State

__all__ = ["RunWriter", "read_run", "read_checkpoint", "summary", "UNITS", "DIMS", "units_of"]

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

    def __init__(self, path, scene, h, monitors, fields, resume=False):
        self.path = str(path)
        self.f = None
        try:
            if resume:
                self.f = h5py.File(self.path, "r+")
                self._check_resumable(scene)
                self._trim()
                self._upgrade()
            else:
                self.f = h5py.File(self.path, "w")
                self._create(scene, h, monitors, fields)
        except OSError as exc:
            self.close()
            raise OutputError(f"{self.path}: cannot {'resume' if resume else 'create'} the run file ({_oserr(exc)})") from None
        except BaseException:
            self.close()
            raise

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

    def _series(self, path, val):
        shape = val.shape
        nbytes = max(val.nbytes, 8)
        rows = int(max(1, min(1024, (1 << 20) // nbytes)))
        d = self.f.create_dataset(path, shape=(0,) + shape, maxshape=(None,) + shape,
                                  dtype="f8" if val.dtype.kind == "f" else "i8", chunks=(rows,) + shape)
        d.dims[0].attach_scale(self.f["time"])
        return d

    # -- resume ------------------------------------------------------------------

    def _check_resumable(self, scene):
        f = self.f
        if "checkpoint" not in f or "scene_toml" not in f.attrs:
            raise OutputError(f"{self.path}: not a varint run file (no checkpoint); cannot resume")
        if f.attrs.get("static", False):
            raise OutputError(f"{self.path}: holds a static equilibrium written by `varint static`, not a run; "
                              "it cannot be resumed (run the scene into another file)")
        if f.attrs["scene_toml"] != scene.text:
            raise OutputError(f"{self.path}: was started from a different scene; resume with the same scene file")

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
        if "external_work" in mon:  # a tip torque under the energy-momentum step: E - W is the conserved quantity
            E = E - mon["external_work"]
            d["energy_deviation_of"] = "energy - external_work"
        # relative to |E(0)|, or to the largest kinetic energy when the run starts at zero energy
        ref = max(abs(E[0]), float(np.max(mon["kinetic_energy"])) if "kinetic_energy" in mon else 0.0, 1e-300)
        d["energy_relative_deviation"] = float(np.max(np.abs(E - E[0])) / ref)
        d["mass_relative_deviation"] = float(np.max(np.abs(mon["mass"] - mon["mass"][0])) / max(abs(mon["mass"][0]), 1e-300)) if "mass" in mon else None
        d["newton_iterations_max"] = int(np.max(mon["newton_iterations"])) if "newton_iterations" in mon else None
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
        if "angular_momentum_cm" in mon:  # rods: the momenta (reactions of supports included) and the frames
            for key in ("linear_momentum", "angular_momentum_cm"):
                v = mon[key]
                d[f"{key}_deviation"] = float(np.max(np.linalg.norm(v - v[0], axis=1)))
            d["frame_orthogonality_max"] = float(np.max(mon["frame_orthogonality"]))
    return d
