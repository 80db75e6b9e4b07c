"""`varint modes` and `varint static` on the straight tube with a liquid in a compliant wall (issue 23, item 5;
docs/theory.md §13.10), against outside truths: the dispersion relation of the linear wall law (docs/theory.md §6,
varint.exact.waves.dispersion_branches), the Moens-Korteweg speed of the tube law, and the uniform static state of a
liquid at rest in a linear wall.  What cannot be linearised or solved is refused in one line."""

import math

import numpy as np
import pytest

import varint
from varint import parse_scene
from varint.analysis.modes import scene_modes
from varint.errors import VarintError
from varint.exact.waves import dispersion_branches
from helpers import RUBBER_WALL_SECTION as RUBBER



def water_tube(wall=RUBBER, nodes=41, parcels=80, ends="", extra="", velocity=0.0):
    return f"""
title = "water in a rubber tube"
[tube]
length = 1.0
nodes = {nodes}
radius = 0.05
{wall}
[fluid]
model = "incompressible"
density = 1000.0
pressure = 0.0
velocity = {velocity!r}
parcels = {parcels}
{ends}
[time]
step = 1e-4
end = 1e-3
{extra}
"""


def test_modes_of_a_water_filled_rubber_tube_against_the_dispersion_relation():
    """Closed straight tube of water in a dynamic linear wall (before issue 23: a LinAlgError traceback): the modes are
    the standing waves k_j = j pi / L of the wall law's dispersion relation, omega^2 = k^2 b / (4 pi rho + a k^2),
    b = beta2 + beta1 k^2 (incompressible branch of docs/theory.md §6), within (k ds)^2 (measured 5e-4, 2e-3, 4.5e-3,
    7.9e-3 for j = 1..4 at 40 elements; second order: 1.3e-4 ... 2.0e-3 at 80)."""
    sc = parse_scene(water_tube())
    w = varint.build_model(sc).tube.wall
    f = np.array([m["frequency"] for m in scene_modes(sc, count=4)["modes"]])
    k = np.arange(1, 5) * math.pi
    lo, _ = dispersion_branches(k, math.inf, 1000.0, 0.05, w.a, w.beta1, w.beta2)
    err = f / lo - 1.0
    assert np.all(np.abs(err) < 1.2 * (k * 1.0 / 40) ** 2 / 2), err
    fine = parse_scene(water_tube(nodes=81, parcels=160))
    f2 = np.array([m["frequency"] for m in scene_modes(fine, count=4)["modes"]])
    order = np.log2(np.abs(err) / np.abs(f2 / lo - 1.0))
    assert np.all(np.abs(order - 2.0) < 0.1), order


def test_modes_of_water_in_a_quasistatic_tube_law_wall_are_moens_korteweg():
    """Quasistatic (a = 0) tube law without tension: the long-wave speed c^2 = beta / (2 rho) (Moens-Korteweg for
    beta = E h / (R0 (1 - nu^2))), the closed tube's modes c j pi / L (before issue 23: a LinAlgError)."""
    wall = '[wall]\nmodel = "quasistatic"\nlaw = "tube-law"\nstiffness = 1.0e4\n'
    f = np.array([m["frequency"] for m in scene_modes(parse_scene(water_tube(wall=wall)), count=3)["modes"]])
    c = math.sqrt(1.0e4 / (2 * 1000.0))
    truth = c * np.arange(1, 4) * math.pi
    assert np.allclose(f, truth, rtol=5e-3), f / truth - 1


def test_static_water_in_a_dented_rubber_tube_is_uniform():
    """`varint static` (the straight tube's Newton, varint.model.statics.tube_static) on water in a linear wall started
    with a Gaussian dent: at rest the pressure is uniform, the wall uniform (the linear law's uniform solution), its
    radius holding the water's volume pi R^2 L, and p - p_ext = beta2 (R - R0) / (2 pi R)."""
    dent = "[[wall.perturbation]]\nfield = \"R\"\nshape = \"gaussian\"\ncenter = 0.4\nwidth = 0.05\namplitude = -0.004\n"
    text = water_tube(wall=RUBBER + dent)
    model = varint.build_model(parse_scene(text))
    t = model.tube
    from varint.model.statics import tube_static

    vol0 = float(np.sum(t.volumes(t.config(np.concatenate([t.q_init, t.lam_init])))))
    z, info = tube_static(model)
    cfg = t.config(z)
    R = math.sqrt(vol0 / math.pi)
    assert np.max(np.abs(cfg.R - R)) < 1e-12 * R
    p = t.wall.beta2 * (R - 0.05) / (2 * math.pi * R)
    assert np.max(np.abs(cfg.mu - p)) < 1e-8 * abs(p), (cfg.mu[:3], p)
    assert np.max(np.abs(t.volumes(cfg) / t.V0 - 1.0)) < 1e-12


def test_varint_static_and_modes_on_the_command_line(tmp_path, capsys):
    from varint.cli import main

    path = tmp_path / "water.toml"
    path.write_text(water_tube())
    assert main(["static", str(path), "-o", str(tmp_path / "s.h5")]) == 0
    assert "static equilibrium of the tube" in capsys.readouterr().out
    assert main(["modes", str(path), "-n", "2", "--about", "static"]) == 0
    assert "frequency" in capsys.readouterr().out


@pytest.mark.parametrize("text,key", [
    (water_tube(wall="", ends='ends = { s0 = "inflow", sL = "outflow" }', velocity=1.0), "no motion left"),
    (water_tube(wall='[wall]\nmodel = "quasistatic"\nlaw = "tube-law"\nstiffness = 1e4\n',
                ends='ends = { s0 = "inflow", sL = "outflow" }', velocity=1.0), "quasistatic [wall]"),
    (water_tube(ends='ends = { s0 = "inflow", sL = "outflow", outflow = "non-reflecting" }', velocity=1.0),
     "absorbs the waves"),
])
def test_modes_that_cannot_be_had_are_one_line(text, key):
    with pytest.raises(VarintError) as e:
        scene_modes(parse_scene(text), count=3, source="scene")
    assert key in str(e.value) and "\n" not in str(e.value) and str(e.value).startswith("scene")


@pytest.mark.parametrize("text,key", [
    (water_tube(ends='ends = { s0 = "inflow", sL = "outflow" }', velocity=1.0), "flows"),
    (water_tube(wall="", extra="").replace('model = "incompressible"', 'model = "ideal-gas"').replace(
        "pressure = 0.0", "pressure = 1e5").replace("density = 1000.0", "density = 1.2"), "nothing to balance"),
])
def test_static_that_cannot_be_had_is_one_line(text, key):
    from varint.model.statics import tube_static

    with pytest.raises(VarintError) as e:
        tube_static(varint.build_model(parse_scene(text)))
    assert key in str(e.value) and "\n" not in str(e.value)


def test_open_tube_modes_carry_a_note_about_the_frozen_flow():
    """An open rubber tube with water flowing in through a velocity inlet: its modes about the initial lattice (the
    inlet a closed end for perturbations, the jet a free one), with a note that the flow is frozen."""
    d = scene_modes(parse_scene(water_tube(ends='ends = { s0 = "inflow", sL = "outflow" }', velocity=1.0)), count=2)
    assert "frozen" in d["note"] and len(d["modes"]) == 2 and d["modes"][0]["frequency"] > 0
