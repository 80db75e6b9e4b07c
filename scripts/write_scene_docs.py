"""Write docs/scenes.md from the scene schema (varint.scene.schema.SCHEMA), so the docs cannot drift.

Run: python scripts/write_scene_docs.py   (tests/test_docs.py checks the file is current)
"""

from pathlib import Path

from varint.scene.schema import NOT_YET, REQUIRED, SCHEMA, _num

HEADER = """# Scene files

A scene is a TOML file in SI units. Its sections switch effects on (docs/theory.md): a scene without
`[wall]` has a rigid wall and no radius unknowns; without `[fluid]` it has no labels; without `[rod]`
the centreline is fixed and straight along x, with `[rod]` and `[fluid]` the fluid rides the moving rod
(the coupled tube, docs/theory.md §10; closed ends; a `[wall]` on a `[rod]` needs a `[fluid]`). Unknown keys
are errors (the nearest valid key is suggested); every problem is reported as one line
`key.path: what is wrong`. `varint check SCENE.toml` prints the resolved parameters, the effects,
the unknowns and the expected invariants.

This page is generated from `varint/scene/schema.py` by `scripts/write_scene_docs.py`.

Perturbation profiles: `cosine` adds amplitude·cos(2πs/wavelength + phase); `gaussian` adds
amplitude·exp(−(s−center)²/(2 width²)); `step` adds amplitude on [from, to]. Pressure and density
perturbations of a gas are isentropic (the other variable follows at the parcel's entropy); a
barotropic fluid follows its barotrope. Regions `[[fluid.initial]]` are applied first, in order,
then perturbations.

Limits, each refused in one line naming the key: no string may hold control characters or line breaks; numbers must
be finite, and so must what is derived from several of them (a gas's entropy ln(p/ρ^γ) and sound speed, the masses,
the wall's coefficients: `fluid.density = 1e300` is refused, naming the most extreme key); a run takes at most 10^9
steps. The run takes ceil(`time.end` / `time.step`) steps (an end within 10⁻⁹ of a multiple of the step counts as that
multiple): when `end` is not a multiple of `step` it ends at the first multiple after `end`, and `varint check` and
`varint run` say so in one line (`examples/garden_hose.toml`: 3637 steps of 0.55 ms, ending at 2.00035 s).
"""


def render():
    out = [HEADER]
    for section, keys in SCHEMA.items():
        name = section or "(top level)"
        out.append(f"\n## `{name}`\n" if section else "\n## top level\n")
        if section.endswith("[]"):
            out.append(f"An array of tables: write each entry as `[[{section[:-2]}]]`.\n")
        out.append("| key | type | unit | default | meaning |\n|---|---|---|---|---|")
        for k in keys:
            if k.default is REQUIRED:
                default = "**required**"
            elif k.default is None:
                default = "–"
            else:
                default = f"`{k.default}`"
            kind = k.kind + (f" ({', '.join(k.choices)})" if k.choices else "")
            rng = ""
            if k.low is not None:
                rng += f" {'>' if k.low_open else '≥'} {k.low:g}"
            if k.high is not None:
                rng += f", ≤ {_num(k.high)}"
            out.append(f"| `{k.name}` | {kind}{rng} | {k.unit} | {default} | {k.doc} |")
    if NOT_YET:
        out.append("\n## Sections not available in this version\n")
        for name, why in NOT_YET.items():
            out.append(f"- `[{name}]`: {why}.")
    return "\n".join(out) + "\n"


if __name__ == "__main__":
    path = Path(__file__).resolve().parent.parent / "docs" / "scenes.md"
    path.write_text(render())
    print(f"wrote {path}")
