"""Run files read by xarray (h5netcdf engine) group by group, units on every dataset, and the
0.1 layout (no dimension scales but /time) still read and resumed."""

from pathlib import Path

import h5netcdf  # noqa: F401 - xarray's engine; both come with the test extra (pip install -e '.[test]')
import h5py
import numpy as np
import pytest
import xarray as xr

from varint import parse_scene, run_scene
from varint.run.io import read_run, units_of

from varint.scene.standard import gas_scene
from varint.scene.text import to_toml

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


def _gas_text(end=5e-5):
    d = gas_scene(nodes=9, parcels=8, end=end)  # dynamic rubber wall: fields/wall/velocity too
    d["output"] = {"every": 1}
    return to_toml(d)


def _liquid_text():
    t = (EXAMPLES / "liquid_pulse_tube_law.toml").read_text()  # incompressible, quasistatic wall
    for a, b in (("nodes = 201", "nodes = 11"), ("parcels = 200", "parcels = 10"), ("end = 0.5", "end = 2.0e-3"),
                 ("every = 10", "every = 1")):
        assert a in t
        t = t.replace(a, b)
    return t


def _rod_text():
    t = (EXAMPLES / "cantilever_rod.toml").read_text()
    for a, b in (("nodes = 51", "nodes = 6"), ("end = 4.0", "end = 0.01"), ("every = 10", "every = 1")):
        assert a in t
        t = t.replace(a, b)
    return t


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    d = tmp_path_factory.mktemp("runs")
    out = {}
    for kind, text in (("gas", _gas_text()), ("liquid", _liquid_text()), ("rod", _rod_text())):
        out[kind] = d / f"{kind}.h5"
        run_scene(parse_scene(text), str(out[kind]), progress=False)
    return out


def _datasets(path):
    """Every dataset by every path (a hard link, like /monitors/time, counts under each of its names)."""
    found = {}

    def visit(name, link):
        obj = h.get(name)
        if isinstance(obj, h5py.Dataset):
            found[name] = dict(obj.attrs)

    with h5py.File(path, "r") as h:
        h.visititems_links(visit)
    return found


@pytest.mark.parametrize("kind", ["gas", "liquid", "rod"])
def test_every_dataset_has_units(runs, kind):
    found = _datasets(runs[kind])
    missing = sorted(name for name, attrs in found.items() if "units" not in attrs)
    assert not missing, missing
    # the physical ones from the table, and the table is what the file says
    expect = {"time": "s", "monitors/energy": "J", "monitors/mass": "kg", "monitors/linear_momentum": "kg m/s",
              "monitors/angular_momentum": "kg m^2/s", "monitors/newton_iterations": "1"}
    if kind == "rod":
        expect.update({"fields/rod/r": "m", "fields/rod/Lambda": "1", "monitors/angular_momentum_cm": "kg m^2/s"})
    else:
        expect.update({"fields/fluid/pressure": "Pa", "fields/fluid/density": "kg/m^3", "fields/fluid/velocity": "m/s",
                       "fields/fluid/s": "m", "fields/wall/R": "m", "monitors/entropy": "J/K"})
    if kind == "gas":
        expect["fields/wall/velocity"] = "m/s"
    for name, units in expect.items():
        assert found[name]["units"] == units, name
    for name, attrs in found.items():
        if name.startswith(("monitors/", "fields/")) and not name.endswith("/time"):
            assert units_of(name) is not None and attrs["units"] == units_of(name), name


def _open(path, group):
    return xr.open_dataset(path, group=group, engine="h5netcdf")


@pytest.mark.parametrize("kind", ["gas", "rod"])
def test_open_dataset_group_by_group(runs, kind):
    path = runs[kind]
    dims = {"monitors": {"energy": ("time",), "linear_momentum": ("time", "component")}}
    if kind == "gas":
        dims["fields/fluid"] = {"pressure": ("time", "parcel"), "density": ("time", "parcel"), "s": ("time", "label"),
                                "velocity": ("time", "label")}
        dims["fields/wall"] = {"R": ("time", "node"), "velocity": ("time", "node")}
    else:
        dims["fields/rod"] = {"r": ("time", "node", "component"), "Lambda": ("time", "node", "component", "axis")}
        dims["monitors"]["angular_momentum_cm"] = ("time", "component")
    with h5py.File(path, "r") as h:
        t = h["time"][...]
        for group, variables in dims.items():
            with _open(path, group) as ds:
                assert np.array_equal(ds["time"].values, t), group  # each group carries its time coordinate
                assert ds["time"].attrs["units"] == "s"
                for name, want in variables.items():
                    da = ds[name]
                    assert da.dims == want, (group, name, da.dims)
                    ref = h[f"{group}/{name}"][...]
                    assert np.array_equal(da.values, ref), (group, name)
                    assert da.attrs["units"] == h[f"{group}/{name}"].attrs["units"]
                # and nothing in the group lacks a dimension name or units
                for name, da in ds.variables.items():
                    assert "units" in da.attrs, (group, name)
        if kind == "gas":
            with _open(path, "fields/fluid") as ds:
                k = len(t) - 1
                assert float(ds["pressure"].isel(time=k, parcel=3)) == h["fields/fluid/pressure"][k, 3]


def test_open_datatree(runs):
    for kind in ("gas", "liquid", "rod"):
        path = runs[kind]
        with xr.open_datatree(path, engine="h5netcdf") as tree:
            groups = set(tree.groups)
            assert {"/monitors", "/fields", "/checkpoint"} <= groups
            if kind == "rod":
                r = tree["fields/rod"]["r"]
                assert r.dims == ("time", "node", "component")
                with h5py.File(path, "r") as h:
                    assert np.array_equal(r.values, h["fields/rod/r"][...])
            else:
                assert tree["fields/wall"]["R"].dims == ("time", "node")
                assert tree["monitors"]["energy"].attrs["units"] == "J"


def test_read_run_lists_no_scales(runs):
    """The time coordinate linked into every group is not a monitor or a field."""
    run = read_run(runs["gas"])
    assert "time" not in run["monitors"]
    assert not any(k.endswith("/time") for k in run["fields"])
    assert set(run["fields"]) == {"fluid/s", "fluid/density", "fluid/pressure", "fluid/velocity", "fluid/entropy",
                                  "wall/R", "wall/velocity"}


def _to_0_1_layout(path):
    """Rewrite a run file the way varint 0.1 wrote it: only /time is a dimension scale (attached to
    axis 0 of every series), no units but on /time, no index dimensions, checkpoint vectors plain."""
    with h5py.File(path, "r+") as h:
        series = []
        for top in ("monitors", "fields"):
            h[top].visititems(lambda name, obj, top=top: series.append(f"{top}/{name}")
                              if isinstance(obj, h5py.Dataset) and not obj.is_scale else None)
        for name in series:
            data = h[name][...]
            del h[name]
            d = h.create_dataset(name, data=data, maxshape=(None,) + data.shape[1:], chunks=(4,) + data.shape[1:])
            d.dims[0].attach_scale(h["time"])
        for g in ["monitors"] + [f"fields/{k}" for k in h["fields"]]:
            del h[g]["time"]
        for dim in ("parcel", "label", "node", "component", "axis"):
            if dim in h:
                del h[dim]
        cp = h["checkpoint"]
        for slot in ("a", "b"):
            if slot not in cp:
                continue
            g = cp[slot]
            for name in [k for k in g if not k.endswith("_index")]:
                data = g[name][...]
                del g[name]
                g.create_dataset(name, data=data)
            for name in [k for k in g if k.endswith("_index")]:
                del g[name]


def test_files_of_the_0_1_layout_read_and_resume(tmp_path):
    text = _gas_text(end=2e-4)
    scene = parse_scene(text)
    ref, old = tmp_path / "ref.h5", tmp_path / "old.h5"
    run_scene(scene, str(ref), progress=False)
    run_scene(scene, str(old), progress=False, max_steps=7)
    _to_0_1_layout(old)
    with h5py.File(old, "r") as h:
        assert "parcel" not in h and "time" not in h["monitors"]
    with pytest.raises(ValueError):  # what 0.1 files did, and why this layout changed
        _open(old, "fields/fluid").load()
    part = read_run(old)
    assert len(part["time"]) == 8 and set(part["fields"]) == set(read_run(ref)["fields"])
    run_scene(scene, str(old), resume=True, progress=False)
    a, b = read_run(ref), read_run(old)
    assert np.array_equal(a["time"], b["time"])
    for key in a["fields"]:
        assert np.allclose(a["fields"][key], b["fields"][key], rtol=1e-12, atol=0), key
    # the resume labelled the old file: xarray reads it now
    with _open(old, "fields/fluid") as ds:
        assert ds["pressure"].dims == ("time", "parcel")
        assert np.array_equal(ds["pressure"].values, b["fields"]["fluid/pressure"])
    assert not [n for n, a in _datasets(old).items() if "units" not in a and not n.startswith("checkpoint/")]


def test_resume_of_a_file_of_this_version(tmp_path):
    """Resuming a labelled file keeps it labelled (nothing attached twice, no duplicate scales)."""
    scene = parse_scene(_gas_text(end=2e-4))
    out = tmp_path / "o.h5"
    run_scene(scene, str(out), progress=False, max_steps=5)
    run_scene(scene, str(out), resume=True, progress=False)
    with h5py.File(out, "r") as h:
        assert len(h["fields/fluid/pressure"].dims[1]) == 1 and len(h["fields/fluid/pressure"].dims[0]) == 1
        assert sorted(k for k in h if k not in ("checkpoint", "fields", "monitors")) == ["component", "label", "node",
                                                                                         "parcel", "time"]
    with _open(out, "monitors") as ds:
        assert ds["energy"].shape == (21,)
