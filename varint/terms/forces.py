"""Non-conservative forces by the discrete Lagrange–d'Alembert principle, and the declarations that
derive a model's invariants.

A force enters a step n -> n+1 as a pair of discrete forces (f^-, f^+) that pair with the variations
at levels n and n+1 (Marsden & West, *Discrete mechanics and variational integrators*, Acta Numerica
2001, §3.2): the step solves pi_n + D1 L_d + f^- = 0 and sets pi_{n+1} = D2 L_d + f^+.  Each force
declares which invariants it breaks and reports the work it does over a step, so that an energy
balance can be monitored.  Terms of the discrete Lagrangian and the ends declare what they break the
same way; :func:`derive_invariants` combines the declarations, so that ``varint check``, the
monitors and the conservation tests follow from them rather than from hand-written lists.

A declaration maps each invariant a piece breaks to what survives of it (``None``: nothing).  Gravity,
for instance, breaks the linear momentum but keeps its components across g, and breaks the angular
momentum but keeps its component along g.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from numba import njit

from ..lattice.lie import hat, k_body

__all__ = ["Declaration", "TipTorque", "derive_invariants", "BASE_INVARIANTS", "k_tip_torque"]

#: what a closed mechanical system without external fields keeps
BASE_INVARIANTS = ("energy", "linear_momentum", "angular_momentum")


@dataclass(frozen=True)
class Declaration:
    """What one piece of a model (term, force, end condition) does to the invariants.

    ``breaks`` maps a broken invariant to the weaker invariant that survives it, or to None.
    """

    name: str
    breaks: dict = field(default_factory=dict)


def derive_invariants(declarations, base=BASE_INVARIANTS):
    """The invariants a model keeps, from its pieces' declarations.

    An invariant no piece breaks is kept.  One that some pieces break survives as the weaker invariant
    they name only if every piece breaking it names the same one (and no piece breaks that one in turn).
    """
    kept = []
    for inv in base:
        survivors = {d.breaks[inv] for d in declarations if inv in d.breaks}
        if not survivors:
            kept.append(inv)
        elif len(survivors) == 1 and None not in survivors:
            weaker = survivors.pop()
            if not any(weaker in d.breaks for d in declarations):
                kept.append(weaker)
    return kept


class Force:
    """What the stepper asks of a non-conservative force (discrete Lagrange–d'Alembert, docs/theory.md §4a).

    ``declaration``: the invariants it breaks.  ``add(pt, d, level)``: add f^- (level 0) or f^+ (level 1)
    at the step's two levels ``pt`` (:class:`varint.terms.step.StepPoint`; ``pt.Lam_1`` holds the new
    frames when level 1 is asked) into ``d`` (:class:`varint.terms.step.Derivatives`), in the blocks'
    variations.  ``jacobian(pt)``: d f^-/d(step unknowns) as a sparse (nz, nz) matrix, or None when f^-
    does not depend on them.  Optional ``after_step(pt)``: update data the force changes once a step is
    accepted (e.g. the parcels' entropy heated by a viscosity), returned by the model as state data.
    """

    declaration = None

    def add(self, pt, d, level):
        raise NotImplementedError

    def jacobian(self, pt):
        return None


@njit(cache=True, inline="always")
def k_tip_torque(c, L, torque, out):
    """out[i] += c (L^T T)_i: a dead torque T in the body frame L of the tip, times c (h/2: the discrete forces f^-,
    f^+ of a step with the level's tip frame; 1: the static generalised force).  TipTorque and the compiled rod step
    (varint.schemes.rod_compiled) both add it with this kernel."""
    for i in range(3):
        out[i] += c * k_body(L, torque, i)


class TipTorque(Force):
    """A dead (spatially fixed) torque T at the tip s = L of a rod.

    Not the gradient of a potential on SO(3), so it enters by Lagrange–d'Alembert: with the tip frame
    Lambda_N at each level, f^- = (h/2) Lambda_N^n T and f^+ = (h/2) Lambda_N^{n+1} T (body components,
    pairing with the variations sigma_N).  It changes no linear momentum (it has no force part); it
    changes the angular momentum by h T per step, and the energy by its work.
    """

    declaration = Declaration("tip_torque", {"energy": None, "angular_momentum": None})

    def __init__(self, torque):
        self.torque = np.asarray(torque, dtype=float)

    def body(self, Lam, c=1.0):
        """The torque in the tip's body frame, c Lambda_N^T T (:func:`k_tip_torque`)."""
        out = np.zeros(3)
        k_tip_torque(c, np.ascontiguousarray(Lam[-1], dtype=np.float64), self.torque, out)
        return out

    def add(self, pt, d, level):
        """Add f^- (``level`` 0, level-n frames) or f^+ (1, level n+1) into the step's derivatives ``d``
        (the stepper's interface: varint.terms.step.StepPoint, Derivatives)."""
        d.rod += self.discrete(pt.h, pt.Lam_n if level == 0 else pt.Lam_1)

    def jacobian(self, pt):
        """d f^- / d(step unknowns): f^- reads level n only."""
        return None

    def discrete(self, h, Lam):
        """f^- (with the level-n frames) or f^+ (level n+1): (N+1, 6), zero but at the tip's sigma."""
        f = np.zeros((Lam.shape[0], 6))
        f[-1, 3:] = self.body(Lam, 0.5 * h)
        return f

    def generalised(self, Lam):
        """The static generalised force at a configuration, (N+1, 6): body torque at the tip."""
        f = np.zeros((Lam.shape[0], 6))
        f[-1, 3:] = self.body(Lam)
        return f

    def stiffness_block(self, Lam):
        """d(generalised force at the tip)/d sigma_N under Lambda_N -> Lambda_N cay(sigma): hat(Lambda_N^T T)."""
        return hat(self.body(Lam))

    def work(self, h, Lam_n, Lam_1, xi):
        """Work over a step, (f^- + f^+) . xi_N / h: the mean body torque times the tip's rotation
        vector (second order in h, like the scheme)."""
        return float((self.discrete(h, Lam_n)[-1, 3:] + self.discrete(h, Lam_1)[-1, 3:]) @ xi[-1] / h)
