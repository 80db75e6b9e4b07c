"""The gallery of the documentation site (docs/gallery.md and docs/gallery/*.png): each example of examples/ run
(shortened where its full run takes minutes, as SHORTER says) and drawn by varint plot, at a small resolution so that
the PNGs can be committed.  Run from the repository's root:  python3 scripts/make_gallery.py [NAME ...]

The pages are regenerated whole; a name given on the command line redraws that example only (its section of
docs/gallery.md is rewritten from GALLERY)."""

from __future__ import annotations

import sys
import tempfile
import time
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import varint  # noqa: E402
from varint.plotting import plot_profiles, plot_run  # noqa: E402
from varint.scene.schema import parse_scene  # noqa: E402

OUT = ROOT / "docs" / "gallery"
SCALE = 0.6  # the PNGs of varint plot (110 dpi) shrunk to this and to 256 colours: ~50 KB each, fit to commit
#: example -> (end [s] of the gallery's run, or None for the whole run; times of the profiles, or None)
SHORTER = {
    "cantilever_rod": (0.6, None),
    "garden_hose": (0.11, None),
    "water_filled_hose": (0.3, None),
    "tumbling_rod": (0.5, None),
    "spinning_shaft": (0.2, None),
    "whirling_hose_energy_momentum": (0.5, None),
    "liquid_pulse_tube_law": (0.1, None),
    "open_pipe_gas": (0.004, None),
    "rigid_horn_gas": (0.008, None),
    "rubber_tube_pulse": (0.005, None),
    "sod_shock_tube": (None, [0.0, 0.1, 0.2]),
    "rubber_tube_traveling_shock": (None, [0.0, 6e-4, 1.2e-3]),
}


def shrink(path):
    """Scale a PNG by SCALE and store it with a 256-colour palette; returns its file name."""
    from PIL import Image

    with Image.open(path) as im:
        im = im.convert("RGB")
        im = im.resize((round(im.width * SCALE), round(im.height * SCALE)), Image.LANCZOS)
        im.quantize(256, dither=Image.Dither.NONE).save(path, optimize=True)
    return Path(path).name


def make(path):
    name = path.stem
    end, at = SHORTER.get(name, (None, None))
    text = path.read_text()
    if end is not None:
        d = tomllib.loads(text)
        old = d["time"]["end"]
        text = text.replace(f"end = {old!r}", f"end = {end!r}", 1) if f"end = {old!r}" in text else text
        text = text.replace(f"end = {old}", f"end = {end}", 1)
    scene = parse_scene(text, source=str(path))
    with tempfile.TemporaryDirectory() as tmp:
        h5 = Path(tmp) / f"{name}.h5"
        t0 = time.perf_counter()
        varint.run_scene(scene, str(h5), progress=False)
        wall = time.perf_counter() - t0
        written = []
        for p in plot_run(h5, OUT):
            written.append(shrink(p))
        if at:
            p, _ = plot_profiles(h5, at, OUT)
            written.append(shrink(p))
    print(f"{name}: t = {scene.time.end:g} s in {wall:.1f} s -> {', '.join(written)}", flush=True)
    return name, scene, written


def page(entries):
    lines = ["# Gallery of the examples", "",
             "Each example of `examples/` run and drawn by `varint plot` (the monitors, the fields; the shock tubes also",
             "`varint plot --at`), by `python3 scripts/make_gallery.py`. Some runs are shortened to keep the script short;",
             "the caption says to which time. Run one yourself with `varint run examples/NAME.toml -o NAME.h5` and",
             "`varint plot NAME.h5`.", ""]
    for name, scene, written in entries:
        lines += [f"## {name}", "", f"{scene.title}", "",
                  f"`varint run examples/{name}.toml` to t = {scene.time.end:g} s"
                  + (" (shortened for the gallery)" if SHORTER.get(name, (None,))[0] is not None else "") + ".", ""]
        for w in sorted(written, key=lambda s: ("fields" not in s, "profiles" not in s, s)):
            lines += [f"![{w}](gallery/{w})", ""]
    return "\n".join(lines)


def main(names):
    OUT.mkdir(parents=True, exist_ok=True)
    paths = sorted((ROOT / "examples").glob("*.toml"))
    if names:
        paths = [p for p in paths if p.stem in names]
    entries = [make(p) for p in paths]
    if not names:
        (ROOT / "docs" / "gallery.md").write_text(page(entries))


if __name__ == "__main__":
    main(sys.argv[1:])
