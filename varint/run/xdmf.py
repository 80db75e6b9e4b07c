"""An XDMF sidecar of a run file, for ParaView and VisIt (``varint export OUT.h5 --xdmf``).

The sidecar ``OUT.xmf`` is a small XML file (XDMF 2, which ParaView's and VisIt's XDMF readers read) describing the
run file's datasets in place: every array is a hyperslab of the HDF5 dataset the run wrote (one record of
``/fields/rod/r``, of ``/fields/fluid/pressure``, ...), so nothing is copied and the sidecar stays a few kilobytes
per record.  It holds one temporal collection per object, with the record times of ``/time``:

- ``rod``: the rod's centreline, its N+1 nodes joined by N line segments (the elements), with the node attributes
  ``R`` (the wall radius: ``/fields/wall/R``, or the scene's constant ``tube.radius`` for a rigid tube on a rod) and
  ``d1``, ``d2``, ``d3`` (the sections' axes, the columns of ``/fields/rod/Lambda``);
- ``fluid``: the fluid's labels, joined by segments that are the parcels, at their positions (``/fields/fluid/position``
  on a rod; on a straight tube the labels along x at ``/fields/fluid/s``), with the label attributes ``s`` and
  ``velocity`` and the parcel (cell) attributes ``pressure``, ``density``, ``entropy``; with open ends only the
  active slots of each record (their number from ``/fields/fluid/active``), so no NaN enters the reader;
- ``wall`` (a straight tube with a wall): the nodes along x, s_n = n L / N, with ``R`` and the wall's ``velocity``.

In ParaView: open ``OUT.xmf`` with the "XDMF Reader", then e.g. the Tube filter (vary the radius by ``R``) on the rod.
"""

from __future__ import annotations

import os
import tomllib
from pathlib import Path
from xml.sax.saxutils import escape, quoteattr

import h5py
import numpy as np

from ..errors import OutputError

__all__ = ["write_xdmf", "xdmf_text"]


def _slab(h5ref, shape, start, count, precision=8, kind="Float"):
    """A HyperSlab DataItem: ``count`` entries of the dataset ``h5ref`` (of ``shape``) from ``start`` (stride 1);
    the reader sees an array of the shape ``count`` without its unit axes."""
    dims = " ".join(str(c) for c in count if c != 1) or "1"
    sel = " ".join(str(v) for v in start) + "  " + " ".join("1" for _ in shape) + "  " + " ".join(str(c) for c in count)
    return (f'<DataItem ItemType="HyperSlab" Dimensions="{dims}" Type="HyperSlab" NumberType="{kind}" Precision="{precision}">'
            f'<DataItem Dimensions="3 {len(shape)}" NumberType="Int" Format="XML">{sel}</DataItem>'
            f'<DataItem Dimensions="{" ".join(str(s) for s in shape)}" NumberType="{kind}" Precision="{precision}" '
            f'Format="HDF">{escape(h5ref)}</DataItem></DataItem>')


def _inline(values, kind="Float"):
    values = np.asarray(values)
    prec = "8" if kind == "Float" else "4"
    text = " ".join(repr(float(v)) if kind == "Float" else str(int(v)) for v in values.ravel())
    dims = " ".join(str(d) for d in values.shape)
    return f'<DataItem Dimensions="{dims}" NumberType="{kind}" Precision="{prec}" Format="XML">{text}</DataItem>'


def _segments(n, shared):
    """Topology of n points joined in order: n - 1 two-node line segments.  Their connectivity is written once per n,
    in ``shared`` (name -> DataItem at the Domain's level), and referenced by each record."""
    name = f"segments_{n}"
    if name not in shared:
        conn = np.stack([np.arange(n - 1), np.arange(1, n)], axis=1)
        shared[name] = _inline(conn, "Int").replace("<DataItem ", f'<DataItem Name="{name}" ', 1)
    return (f'<Topology TopologyType="Polyline" NodesPerElement="2" NumberOfElements="{n - 1}">'
            f'<DataItem Reference="XML">/Xdmf/Domain/DataItem[@Name="{name}"]</DataItem></Topology>')


def _shared_values(name, values, shared):
    """A constant array written once at the Domain's level (``shared``) and referenced."""
    if name not in shared:
        shared[name] = _inline(values).replace("<DataItem ", f'<DataItem Name="{name}" ', 1)
    return f'<DataItem Reference="XML">/Xdmf/Domain/DataItem[@Name="{name}"]</DataItem>'


def _attribute(name, center, item, vector=False):
    return (f'<Attribute Name={quoteattr(name)} AttributeType="{"Vector" if vector else "Scalar"}" Center="{center}">'
            + item + "</Attribute>")


def xdmf_text(h5path, href=None):
    """The XDMF document (a string) describing the run file ``h5path`` in place; ``href`` is how the document names
    the HDF5 file (default its file name: the sidecar sits beside it).  Raises OutputError for a file that is not a
    run file or has no field to show."""
    href = href or Path(h5path).name
    try:
        f = h5py.File(h5path, "r", locking=False)
    except OSError as exc:
        raise OutputError(f"{h5path}: not a readable varint run file ({exc.__class__.__name__})") from None
    with f:
        if "time" not in f or "fields" not in f:
            raise OutputError(f"{h5path}: not a varint run file with fields (no /time or /fields)")
        K = int(f.attrs.get("records", f["time"].shape[0]))
        times = f["time"][:K]
        try:
            scene = tomllib.loads(str(f.attrs.get("scene_toml", "")))
        except tomllib.TOMLDecodeError:
            scene = {}
        F = f["fields"]

        def ds(path):
            return F[path] if path in F else None

        def ref(path):
            return f"{href}:/fields/{path}"

        grids, shared = [], {}
        r, Lam, R = ds("rod/r"), ds("rod/Lambda"), ds("wall/R")
        if r is not None:
            n1 = r.shape[1]
            steps = []
            radius = scene.get("tube", {}).get("radius")
            for k in range(K):
                parts = [f'<Time Value="{float(times[k])!r}"/>', _segments(n1, shared),
                         '<Geometry GeometryType="XYZ">' + _slab(ref("rod/r"), r.shape, (k, 0, 0), (1, n1, 3)) + "</Geometry>"]
                if R is not None and R.shape[1] == n1:
                    parts.append(_attribute("R", "Node", _slab(ref("wall/R"), R.shape, (k, 0), (1, n1))))
                elif isinstance(radius, (int, float)):
                    parts.append(_attribute("R", "Node", _inline(np.full(n1, float(radius)))))  # (a reference has no dimensions for the reader)
                if Lam is not None:
                    for j in range(3):
                        parts.append(_attribute(f"d{j + 1}", "Node", _slab(ref("rod/Lambda"), Lam.shape, (k, 0, 0, j), (1, n1, 3, 1)),
                                                vector=True))
                steps.append(parts)
            grids.append(("rod", steps))
        s = ds("fluid/s")
        if s is not None:
            X = ds("fluid/position")
            active = ds("fluid/active")
            nslots = s.shape[1]
            counts = (np.sum(active[:K] != 0, axis=1).astype(int) if active is not None else np.full(K, nslots))
            steps = []
            for k in range(K):
                n = int(counts[k])
                if n < 2:
                    steps.append([f'<Time Value="{float(times[k])!r}"/>'])
                    continue
                parts = [f'<Time Value="{float(times[k])!r}"/>', _segments(n, shared)]
                if X is not None:
                    parts.append('<Geometry GeometryType="XYZ">' + _slab(ref("fluid/position"), X.shape, (k, 0, 0), (1, n, 3))
                                 + "</Geometry>")
                else:  # a straight tube: the labels along x
                    zeros = _shared_values(f"zeros_{n}", np.zeros(n), shared)
                    parts.append('<Geometry GeometryType="X_Y_Z">' + _slab(ref("fluid/s"), s.shape, (k, 0), (1, n))
                                 + zeros + zeros + "</Geometry>")
                for name in ("s", "velocity"):
                    d = ds(f"fluid/{name}")
                    if d is not None:
                        parts.append(_attribute(name, "Node", _slab(ref(f"fluid/{name}"), d.shape, (k, 0), (1, n))))
                for name in ("pressure", "density", "entropy"):
                    d = ds(f"fluid/{name}")
                    if d is not None:
                        parts.append(_attribute(name, "Cell", _slab(ref(f"fluid/{name}"), d.shape, (k, 0), (1, n - 1))))
                steps.append(parts)
            grids.append(("fluid", steps))
        if r is None and R is not None:  # a straight tube's wall: nodes along x
            n1 = R.shape[1]
            L = float(scene.get("tube", {}).get("length", 0.0)) or (float(np.nanmax(s[0])) if s is not None else 1.0)
            zeros = _shared_values(f"zeros_{n1}", np.zeros(n1), shared)
            xs = _shared_values("wall_nodes_x", np.linspace(0.0, L, n1), shared)
            W = ds("wall/velocity")
            steps = []
            for k in range(K):
                parts = [f'<Time Value="{float(times[k])!r}"/>', _segments(n1, shared),
                         '<Geometry GeometryType="X_Y_Z">' + xs + zeros + zeros + "</Geometry>",
                         _attribute("R", "Node", _slab(ref("wall/R"), R.shape, (k, 0), (1, n1)))]
                if W is not None and W.shape[1] == n1:
                    parts.append(_attribute("velocity", "Node", _slab(ref("wall/velocity"), W.shape, (k, 0), (1, n1))))
                steps.append(parts)
            grids.append(("wall", steps))
        if not grids:
            raise OutputError(f"{h5path}: no rod, fluid or wall field to export")
        title = str(f.attrs.get("title", ""))
    out = ['<?xml version="1.0" ?>', '<!DOCTYPE Xdmf SYSTEM "Xdmf.dtd" []>',
           "<!-- " + f"{title}: the datasets of {href}, in place (written by varint export)".replace("-", "\u2010") + " -->",
           '<Xdmf Version="2.0">', "<Domain>"] + list(shared.values())
    for name, steps in grids:
        out.append(f'<Grid Name="{name}" GridType="Collection" CollectionType="Temporal">')
        for k, parts in enumerate(steps):
            out.append(f'<Grid Name="{name}_{k}" GridType="Uniform">')
            out += parts
            out.append("</Grid>")
        out.append("</Grid>")
    out += ["</Domain>", "</Xdmf>", ""]
    return "\n".join(out)


def write_xdmf(h5path, out=None, force=False):
    """Write the sidecar of ``h5path`` (default ``OUT.xmf`` beside ``OUT.h5``); returns its path.  An existing file
    is replaced only with ``force``; the HDF5 file is named relative to the sidecar's folder."""
    h5path = Path(h5path)
    out = Path(out) if out else h5path.with_suffix(".xmf")
    if out.resolve() == h5path.resolve():
        raise OutputError(f"{out}: the sidecar would replace the run file")
    if out.exists() and not force:
        raise OutputError(f"{out} exists; pass --force to replace it")
    href = os.path.relpath(h5path.resolve(), out.resolve().parent)
    text = xdmf_text(h5path, href=href)
    try:
        out.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise OutputError(f"{out}: cannot write ({exc.strerror or exc.__class__.__name__})") from None
    return out
