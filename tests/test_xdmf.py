"""`varint export OUT.h5 --xdmf`: the XDMF sidecar opened by ParaView's XDMF reader.

The reader is VTK's ``vtkXdmfReader`` (module ``vtkIOXdmf2``, from the ``vtk`` wheel on PyPI, in the ``test`` extra):
the "XDMF Reader" ParaView and VisIt's XDMF plugin build on, with its own HDF5 library.  It reads the centreline of
the rod, the fluid's labels and parcels and the wall radius at two times, which must be the run file's data read by
h5py.  (meshio's XDMF time-series reader was tried first: it reads one geometry for all times and whole datasets
only, no hyperslab, so it cannot read a moving centreline stored in place.)
"""

from pathlib import Path

import h5py
import numpy as np
import pytest
from vtkmodules.util.numpy_support import vtk_to_numpy
from vtkmodules.vtkCommonExecutionModel import vtkStreamingDemandDrivenPipeline
from vtkmodules.vtkIOXdmf2 import vtkXdmfReader

from varint.cli import main
from varint.scene.standard import gas_scene
from varint.scene.text import to_toml

ROOT = Path(__file__).resolve().parent.parent


class Xdmf:
    """The sidecar opened with vtkXdmfReader: its times, and the blocks (name -> dataset) at a time."""

    def __init__(self, path):
        self.reader = vtkXdmfReader()
        self.reader.SetFileName(str(path))
        self.reader.UpdateInformation()
        self.times = list(self.reader.GetOutputInformation(0).Get(vtkStreamingDemandDrivenPipeline.TIME_STEPS()))

    def at(self, t):
        self.reader.UpdateTimeStep(t)
        out = self.reader.GetOutputDataObject(0)
        if not hasattr(out, "GetNumberOfBlocks"):
            return {"one": out}
        return {out.GetMetaData(b).Get(out.NAME()): out.GetBlock(b) for b in range(out.GetNumberOfBlocks())}


def points(block):
    return vtk_to_numpy(block.GetPoints().GetData())


def point_array(block, name):
    return vtk_to_numpy(block.GetPointData().GetArray(name))


def cell_array(block, name):
    return vtk_to_numpy(block.GetCellData().GetArray(name))


def test_the_centreline_wall_radius_and_fluid_of_a_coupled_run_open_in_paraviews_reader(tmp_path, capsys):
    text = (ROOT / "examples" / "water_filled_hose.toml").read_text()
    text = text.replace("end = 2.0", "end = 0.012").replace("every = 10", "every = 4")
    (tmp_path / "hose.toml").write_text(text)
    h5 = tmp_path / "hose.h5"
    assert main(["run", str(tmp_path / "hose.toml"), "-o", str(h5), "-q"]) == 0
    assert main(["export", str(h5), "--xdmf"]) == 0
    xmf = tmp_path / "hose.xmf"
    assert f"wrote {xmf}" in capsys.readouterr().out
    assert xmf.stat().st_size < 60_000  # a description, not a copy

    with h5py.File(h5, "r") as f:
        t = f["time"][:]
        r, R, Lam = f["fields/rod/r"][:], f["fields/wall/R"][:], f["fields/rod/Lambda"][:]
        X, p, u = f["fields/fluid/position"][:], f["fields/fluid/pressure"][:], f["fields/fluid/velocity"][:]
    x = Xdmf(xmf)
    assert np.array_equal(x.times, t)
    assert len(t) == 4 and np.max(np.abs(r[-1] - r[0])) > 1e-5  # the hose has moved
    for k in (1, len(t) - 1):
        blocks = x.at(t[k])
        rod, fluid = blocks["rod"], blocks["fluid"]
        assert np.array_equal(points(rod), r[k])  # bit for bit: the reader read the run's own doubles
        assert rod.GetNumberOfCells() == r.shape[1] - 1  # the elements, joining the nodes in order
        assert np.array_equal(point_array(rod, "R"), R[k])
        assert np.array_equal(point_array(rod, "d1"), Lam[k, :, :, 0])
        assert np.array_equal(points(fluid), X[k])
        assert np.array_equal(cell_array(fluid, "pressure"), p[k])  # the parcels are the cells between labels
        assert np.array_equal(point_array(fluid, "velocity"), u[k])

    assert main(["export", str(h5), "--xdmf"]) == 2  # an existing sidecar is kept
    assert "--force" in capsys.readouterr().err
    assert main(["export", str(h5), "--xdmf", "--force", "-o", str(tmp_path / "sub" / "h.xmf")]) == 2  # no such folder
    (tmp_path / "sub").mkdir()
    assert main(["export", str(h5), "--xdmf", "-o", str(tmp_path / "sub" / "h.xmf")]) == 0
    assert np.array_equal(points(Xdmf(tmp_path / "sub" / "h.xmf").at(t[2])["rod"]), r[2])  # ../hose.h5 from there


def test_a_straight_tube_opens_along_x_with_its_wall(tmp_path):
    d = gas_scene(nodes=9, parcels=8, end=3e-5, h=1e-5,
                  perturbation=[{"field": "pressure", "shape": "gaussian", "amplitude": 5e3, "center": 0.5, "width": 0.1}])
    (tmp_path / "tube.toml").write_text(to_toml(d))
    h5 = tmp_path / "tube.h5"
    assert main(["run", str(tmp_path / "tube.toml"), "-o", str(h5), "-q"]) == 0
    assert main(["export", str(h5), "--xdmf"]) == 0
    with h5py.File(h5, "r") as f:
        t, s, p, R = f["time"][:], f["fields/fluid/s"][:], f["fields/fluid/pressure"][:], f["fields/wall/R"][:]
    x = Xdmf(tmp_path / "tube.xmf")
    for k in (0, len(t) - 1):
        blocks = x.at(t[k])
        fl, wall = blocks["fluid"], blocks["wall"]
        assert np.array_equal(points(fl)[:, 0], s[k]) and not np.any(points(fl)[:, 1:])
        assert np.array_equal(cell_array(fl, "pressure"), p[k])
        assert np.allclose(points(wall)[:, 0], np.linspace(0.0, 1.0, 9)) and np.array_equal(point_array(wall, "R"), R[k])


def test_open_ends_export_only_the_active_slots(tmp_path):
    """Open ends (docs/output.md): a varying number of labels on fixed slots, NaN beyond; each record's grid has its
    own labels only.  A file written by hand in that layout."""
    h5 = tmp_path / "open.h5"
    K, slots = 3, 7
    n = [4, 6, 5]
    s = np.full((K, slots), np.nan)
    p = np.full((K, slots - 1), np.nan)
    active = np.zeros((K, slots), dtype=np.int64)
    for k in range(K):
        s[k, :n[k]] = np.linspace(0.0, 1.0, n[k]) + 0.01 * k
        p[k, :n[k] - 1] = 1e5 + np.arange(n[k] - 1) + 10 * k
        active[k, :n[k]] = 1
    with h5py.File(h5, "w") as f:
        f.attrs["records"] = K
        f.attrs["scene_toml"] = 'title = "t"\n[tube]\nlength = 1.0\n'
        f["time"] = [0.0, 0.5, 1.0]
        f["fields/fluid/s"], f["fields/fluid/pressure"], f["fields/fluid/active"] = s, p, active
    from varint.run.xdmf import write_xdmf

    x = Xdmf(write_xdmf(h5))
    for k in range(K):
        fl = x.at([0.0, 0.5, 1.0][k])["one"]
        assert np.array_equal(points(fl)[:, 0], s[k, :n[k]])
        assert np.array_equal(cell_array(fl, "pressure"), p[k, :n[k] - 1])
    with pytest.raises(Exception, match="not a readable varint run file"):
        write_xdmf(tmp_path / "missing.h5", tmp_path / "m.xmf")
