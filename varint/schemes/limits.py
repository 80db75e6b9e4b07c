"""The chart's limit, said once: a frame that turns by more than 90 degrees in one step (|xi| > XI_MAX in the Cayley
chart, docs/theory.md §9) is not a result to keep, whichever backend of the midpoint scheme found it."""

from __future__ import annotations

import math

from ..errors import SolverError
from . import em_rod

__all__ = ["chart_limit_error", "with_scheme_hint"]


def chart_limit_error(model, n, h, node, turn):
    """The one-line SolverError of node ``node`` turning by the Cayley coordinate ``turn`` (> XI_MAX) at step ``n``,
    naming the energy-momentum scheme where it covers the model (its directors have no chart limit)."""
    deg = math.degrees(2.0 * math.atan(0.5 * turn))
    covered = em_rod.supports(model) is None
    hint = ("; reduce time.step, or step it with time.scheme = 'energy-momentum', whose directors have no chart limit "
            "(docs/theory.md §12a)" if covered else "; reduce time.step")
    return SolverError(f"step {n} (t = {n * h:.6g} s): node {node} turns by {deg:.0f} degrees in one step (more than "
                       f"90){hint}", step=n, time=n * h, cure="energy-momentum" if covered else None)


def with_scheme_hint(model, exc):
    """``exc`` (a SolverError of the midpoint or trapezoidal step that step control could not recover) with the
    energy-momentum scheme named where it covers the model: its discrete gradients keep the energy to the solver's
    tolerance, so a run that the midpoint loses to an unresolved fast mode often runs with it (docs/theory.md §12c;
    ``scripts/water_hose_long_run.py``: the water-filled hose fails at 2.4 s with the midpoint, runs 20 s with it)."""
    if exc.cure is not None or em_rod.supports(model) is not None:
        return exc  # (it names its cure already: the scheme, or a shock's viscosity, which no scheme replaces)
    return SolverError(f"{exc}; time.scheme = 'energy-momentum' may run it (its energy is exact to the solver's "
                       "tolerance, docs/theory.md §12)", step=exc.step, time=exc.time, residual=exc.residual,
                       rate=exc.rate, cure="energy-momentum")
