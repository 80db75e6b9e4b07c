"""varint: structure-preserving variational integrator for flexible, expandable tubes conveying fluid.

Public API::

    scene = varint.load_scene("examples/rubber_tube_pulse.toml")
    model = varint.build_model(scene)
    sim = varint.Simulation(model)        # one stepper whatever the scene's effects
    sim.step(); sim.monitors(); sim.fields()
    varint.run_scene(scene, "out.h5")

The discrete Lagrangian and its stationarity conditions are in docs/theory.md.
"""

from .version import __version__  # noqa: E402
from .errors import OutputError, SceneError, SolverError, VarintError  # noqa: E402
from .model.model import Model, build_model  # noqa: E402
from .run.runner import make_simulation, run_scene  # noqa: E402
from .scene.schema import Scene, load_scene, parse_scene  # noqa: E402
from .run.simulation import Simulation  # noqa: E402
from .schemes.state import State  # noqa: E402

__all__ = ["__version__", "load_scene", "parse_scene", "Scene", "build_model", "Model", "Simulation", "State",
           "run_scene", "make_simulation", "VarintError", "SceneError", "SolverError", "OutputError"]
