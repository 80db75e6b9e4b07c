"""The state a step takes and returns, and the statistics of a step: the contract between schemes and the driver.

Layouts of the vectors: :mod:`varint.model.model`; checkpoints store them (docs/output.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["State", "StepStats"]


@dataclass
class State:
    """Everything a restart needs: level n, (q_n, p_n), the last half-level algebraic unknowns
    and the last step's predictor data (layouts: :mod:`varint.model`)."""

    n: int
    t: float
    q: np.ndarray
    p: np.ndarray
    lam: np.ndarray
    v: np.ndarray
    q_prev: np.ndarray | None = None  #: q_{n-1}, to evaluate the last step's energy
    #: data that forces change as the run goes, by name (:meth:`varint.model.Model.state_data`), or None
    data: dict | None = None

    def copy(self):
        return State(self.n, self.t, self.q.copy(), self.p.copy(), self.lam.copy(), self.v.copy(),
                     None if self.q_prev is None else self.q_prev.copy(),
                     None if self.data is None else {k: np.array(v, copy=True) for k, v in self.data.items()})


@dataclass
class StepStats:
    """A run's statistics: the last step's Newton iterations and evaluations, and totals over the run."""

    iterations: int = 0
    n_residual: int = 0
    n_jacobian: int = 0
    total_iterations: int = 0
    total_jacobians: int = 0
    fallbacks: int = 0  #: steps that needed a fallback (a damped Newton restart, or two half steps)
    halved_steps: int = 0  #: steps that failed at h and were taken as shorter steps (step control, theory §4b)

    def record(self, report):
        """Add one step's :class:`varint.schemes.base.StepReport`."""
        self.iterations, self.n_residual, self.n_jacobian = report.iterations, report.n_residual, report.n_jacobian
        self.total_iterations += report.iterations
        self.total_jacobians += report.n_jacobian
        self.fallbacks += int(report.fallback)
        self.halved_steps += int(report.halved)
