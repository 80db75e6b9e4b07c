"""One model of a scene: named blocks of unknowns, the terms of its discrete Lagrangian, its forces.

A scene's effects decide which blocks exist (docs/theory.md §3, §9, §10.1):

========  ===========================================  =====================  ===========================
block     what                                         kind                   present when
========  ===========================================  =====================  ===========================
s         fluid labels                                 inertial               ``[fluid]``
R         wall radii at the nodes                      inertial / algebraic   ``[wall]`` dynamic / quasistatic
mu        pressure multipliers                         algebraic              incompressible ``[fluid]``
r         rod node positions                           inertial               ``[rod]``
Lambda    rod frames (SO(3), Cayley retraction)        inertial               ``[rod]``
========  ===========================================  =====================  ===========================

Without ``[rod]`` the centreline is fixed and straight (no r, Lambda unknowns); without ``[wall]`` the
radius is prescribed (no R unknowns).  The blocks are grouped in two parts that own their physics:
:class:`varint.terms.tube.TubePart` (s, R, mu on the fixed centreline) and :class:`varint.terms.rod.RodPart`
(r, Lambda).  The discrete Lagrangian is the sum of the step terms of :mod:`varint.terms.step`
(kinetic terms included); one stepper (:class:`varint.run.simulation.Simulation`) solves its discrete
Euler-Lagrange equations whatever blocks are present.

Layouts (documented because checkpoints store them; docs/output.md)
-------------------------------------------------------------------
step unknowns ``z``
    ``[tube inertial q_{n+1} | tube algebraic lam | rod (b_j, xi_j) on the support mask, node-major |
    rod multipliers n (inextensible rod: N x ncomp, element-major)]``
    with b_j = Lambda_j^n^T (r_j^{n+1} - r_j^n) (body-frame displacement) and
    xi_j = cay^-1(Lambda_j^n^T Lambda_j^{n+1}): the charts of the r and Lambda blocks.
half-level unknowns ``lam`` (``State.lam``)
    ``[tube algebraic lam (quasistatic radii, multipliers mu) | rod multipliers n]`` of the last step
level vector ``q`` (``State.q``)
    ``[tube q | rod r (relative to the floating origin) | rod Lambda | rod origin (3)]``
momenta ``p`` (``State.p``)
    ``[tube p | rod spatial p (N+1, 3) | rod body Pi (N+1, 3)]`` (the rod's on every node: supported
    components hold the support's reaction impulse)
predictor data ``v`` (``State.v``)
    ``[tube velocities | rod b (N+1, 3) | rod xi (N+1, 3)]`` of the last step
"""

from __future__ import annotations

import numpy as np

from ..errors import SceneError
from ..terms.forces import Declaration, derive_invariants
from ..terms.rod import RodPart, pack_level
from .statics import static_equilibrium
from ..terms.tube import TubePart

__all__ = ["Model", "build_model"]


class Model:
    """The discrete model of one scene.  Build it with :func:`build_model`."""

    def __init__(self, scene):
        self.scene = scene
        self.L = scene.tube.length
        self.N = scene.tube.nodes - 1
        self.ds = self.L / self.N
        self.scheme = scene.time.scheme
        has_tube_effect = scene.fluid is not None or scene.wall is not None
        #: the s, R, mu blocks on the fixed straight centreline (None without [fluid] and [wall], unless
        #: there is no rod either: an empty tube is still a valid, if dull, scene)
        self.tube = TubePart(scene) if has_tube_effect or scene.rod is None else None
        #: the r, Lambda blocks (None without [rod])
        self.rod = RodPart(scene) if scene.rod is not None else None
        if self.rod is not None and (scene.rod.initial or {}).get("shape") == "steady_rotation":
            # the initial shape is the steady rotation at the initial spin (docs/theory.md §9)
            Lam, r, info = static_equilibrium(self.rod, spin=self.rod.spin)
            self.rod.set_configuration(Lam, r)
            self.rod.steady_rotation = info
        #: the coupled tube (docs/theory.md §10): the fluid's terms read both parts
        self.coupled = self.tube is not None and self.rod is not None  # (a [wall] on a [rod] comes with a [fluid]: varint.scene.schema)
        if self.coupled and self.tube.open:
            # open ends on the rod (docs/theory.md §13.1): the parcels start with their volumes on the rod's centreline
            self.tube.coupled_rebase(self.open_volumes(np.r_[self.tube.piston, self.tube.q_init], self.rod.Lam0, self.rod.r0))
        self._layout()
        #: non-conservative forces (discrete Lagrange-d'Alembert, varint.terms.forces.Force), every part's
        self.forces = [f for part in (self.tube, self.rod) if part is not None for f in getattr(part, "forces", [])]
        for f in self.forces:
            if hasattr(f, "bind"):  # a force reading both parts (the coupled tube's shock capturing)
                f.bind(self)
        #: the evolving data at t = 0 (a force heats them in place as a run goes: every new run starts from these)
        self.initial_data = self.state_data()

    # -- layout -----------------------------------------------------------------------

    def _layout(self):
        t, r = self.tube, self.rod
        nz_t = t.nz if t is not None else 0
        nq_t = t.nq if t is not None else 0
        nl_t = t.nlam if t is not None else 0
        nz_r = r.nz if r is not None else 0
        nl_r = r.nlam if r is not None else 0
        #: slices of each part in the step unknowns, the level vector, the momenta and State.lam
        self.tube_z, self.rod_z = slice(0, nz_t), slice(nz_t, nz_t + nz_r)
        self.rod_lam_z = slice(nz_t + nz_r, nz_t + nz_r + nl_r)  #: the rod's multipliers (inextensible rod)
        n1 = (self.N + 1) if r is not None else 0
        self.tube_q, self.rod_q = slice(0, nq_t), slice(nq_t, nq_t + (12 * n1 + 3 if r is not None else 0))
        self.tube_p, self.rod_p = slice(0, nq_t), slice(nq_t, nq_t + 6 * n1)
        self.tube_lam, self.rod_lam = slice(0, nl_t), slice(nl_t, nl_t + nl_r)
        self.nz = nz_t + nz_r + nl_r
        #: unknown blocks by name: indices (slice or array) into the step unknowns z
        self.layout = dict(t.layout) if t is not None else {}
        if r is not None:
            idx = np.full((self.N + 1, 6), -1)
            idx[r.mask] = nz_t + np.arange(nz_r)
            for name, cols in (("r", slice(0, 3)), ("Lambda", slice(3, 6))):
                sel = idx[:, cols]
                self.layout[name] = np.sort(sel[sel >= 0])
            if nl_r:
                self.layout["n"] = self.rod_lam_z  # the element forces that hold Gamma = chi
        #: the kinds of the blocks present (the stepper's options and checks follow from them)
        self.has_frames = r is not None

    @property
    def unknown_names(self):
        return list(self.layout)

    def state_data(self):
        """Data that forces change as the run goes (e.g. the parcels' entropy under a heating viscosity):
        ``{name: array}`` stored with each state (``State.data``, checkpoints), or None when nothing does."""
        data = {}
        for part in (self.tube, self.rod):
            if part is not None and hasattr(part, "evolving_data"):
                data.update(part.evolving_data())
        return data or None

    def set_state_data(self, data):
        """Restore what :meth:`state_data` returned (a resumed run continues with the heated entropies)."""
        for part in (self.tube, self.rod):
            if part is not None and hasattr(part, "set_evolving_data"):
                part.set_evolving_data(data)
        if self.tube is not None and self.tube.open:
            self._layout()  # open ends: the lattice (and with it the blocks' sizes) may have changed

    # -- initial state -------------------------------------------------------------------

    def initial_state(self, h):
        """(q, p, lam, v) at t = 0 in the layouts of the module docstring; ``v`` is the predictor's
        data of a fictitious previous step of size ``h`` (the rod's b and xi scale with h)."""
        q, p, lam, v = [], [], [], []
        t, r = self.tube, self.rod
        if t is not None:
            q.append(t.q_init)
            p.append(t.p_init)
            lam.append(t.lam_init)
            v.append(t.v_init)
        if r is not None:
            q.append(pack_level(r.Lam0, r.r0))
            p += [r.p0.ravel(), r.Pi0.ravel()]
            lam.append(np.zeros(r.nlam))  # the multipliers of Gamma = chi: no force in the initial shape's strains
            # the last step's displacement in the body frame it started from, and xi: exact for a rigid rotation
            v += [np.einsum("nji,nj->ni", r.Lam0, h * r.v0).ravel(), (h * r.omega0).ravel()]
        cat = lambda xs: np.concatenate(xs) if xs else np.empty(0)  # noqa: E731
        q, p, lam, v = cat(q), cat(p), cat(lam), cat(v)
        if self.coupled:
            legendre = self.initial_legendre()
            p[self.rod_p.start:self.rod_p.start + 3 * (self.N + 1)] += legendre["rod_p"].ravel()
            sl = self.tube.layout["s"]
            free = self.free_labels
            p[self.tube_p][sl] = legendre["label_p"][free]
            v[self.tube_p][sl] = legendre["sdot"][free]
        return q, p, lam, v

    def initial_legendre(self):
        """The fluid's share of the initial momenta of the coupled tube (docs/theory.md §10.5, "Initial momenta").

        Labels move with the rod and, relative to it, at ``fluid.velocity`` (and initial regions) along the
        centreline: ``sdot_k = u_k / |X'_k|``, ``Xdot_k = sum_i N_i(s_k) v_i + X'_k sdot_k``.  Returns the nodal
        momenta sum_k mbar_k N_j(s_k) Xdot_k (N+1, 3), the label momenta mbar_k Xdot_k . X'_k (M+1,),
        sdot (M+1,), Xdot (M+1, 3) and the fluid's kinetic energy ``1/2 sum mbar_k |Xdot_k|^2``.
        """
        t, rod = self.tube, self.rod
        cfg = t.config(np.concatenate([t.q_init, t.lam_init]))
        u = np.zeros(t.M + 1)
        u[self.free_labels] = t.v_init[t.layout["s"]]  # the closed ends' labels do not move along the tube
        if t.open and t.n_fixed:
            u[0] = t.U_in  # the inlet's piston
        if t.periodic:
            u[-1] = u[0]
        from ..terms.coupled import label_velocity_map

        nodes, Nw, dNw, X, dX, _ = self.centreline(cfg.s, rod.r0)
        sdot = u / np.linalg.norm(dX, axis=1)
        v_nodes = rod.v0 * rod.mask[:, :3]  # a held node does not move, whatever rod.initial.velocity says
        # the kinetic metric's map (the one construction, varint.terms.coupled): Xdot = Jx vel, p = Jx^T mbar Xdot
        n1 = rod.N + 1
        Jx = label_velocity_map(nodes, Nw, dX, n1)
        vel = np.concatenate([np.concatenate([v_nodes, np.zeros((n1, 3))], axis=1).ravel(), sdot])
        Xdot = (Jx @ vel).reshape(-1, 3)
        mbar = t.label_mass_all
        p = Jx.T @ (np.repeat(mbar, 3) * Xdot.ravel())
        return {"rod_p": p[:6 * n1].reshape(n1, 6)[:, :3].copy(), "label_p": p[6 * n1:], "sdot": sdot, "Xdot": Xdot,
                "kinetic": 0.5 * float(np.sum(mbar * np.sum(Xdot * Xdot, axis=1)))}

    @property
    def free_labels(self):
        """Which of the M+1 labels are unknowns: the interior ones (closed ends) or 0..M-1 (periodic: label M
        is label 0 shifted by the period)."""
        t = self.tube
        if t.open:  # open ends: every label but a velocity inlet's piston
            return slice(t.n_fixed, None)
        return slice(0, -1) if t.periodic else slice(1, -1)

    def open_volumes(self, s, Lam, r):
        """The stretched volumes of the open coupled tube's parcels (labels ``s``) on the extended lattice (§13.1)."""
        from ..terms.coupled import element_strains, stretched_volumes_of

        ext = self.tube.ext
        G, _, _ = element_strains(ext.frames(Lam), ext.positions(r), self.tube.ds)
        return stretched_volumes_of(np.asarray(s) + ext.shift, ext.pad(self.tube.R_reference), G, self.tube.ds, False)

    def centreline(self, s, r):
        """``centreline_and_weights`` of the labels ``s`` on the rod positions ``r`` (N+1, 3): a periodic tube's
        reads nodes 0..N-1 and wraps with the period (docs/theory.md §10.2)."""
        from ..lattice.centreline import centreline_and_weights

        rod = self.rod
        if rod.periodic:
            return centreline_and_weights(s, r[:-1], self.tube.ds, True, rod.period)
        if self.tube.open:
            # the extended centreline (§13.1); the weights of the ghost nodes are passed on to the real nodes they tie
            ext = self.tube.ext
            nodes, Nw, dNw, X, dX, d2X = centreline_and_weights(np.asarray(s) + ext.shift, ext.positions(r), self.tube.ds)
            k = len(nodes)
            wn, ww = ext.node_weights()
            fold = lambda A: (A[:, :, None] * ww[nodes]).reshape(k, -1)  # noqa: E731
            return wn[nodes].reshape(k, -1), fold(Nw), fold(dNw), X, dX, d2X
        return centreline_and_weights(s, r, self.tube.ds)

    def upgrade_level(self, q):
        """A level vector from a checkpoint written before the rod's floating origin existed gains it."""
        if self.rod is not None and len(q) == self.rod_q.stop - 3:
            return np.concatenate([q, np.zeros(3)])
        return q

    # -- declarations ---------------------------------------------------------------------

    def declarations(self):
        """What each term, force and end does to the invariants (varint.terms.forces.Declaration)."""
        decl = self.rod.declarations() if self.rod is not None else []
        if self.coupled:
            # docs/theory.md §10.6: the fluid's terms keep the rigid motions; its gravity breaks what the rod's does
            decl.append(Declaration("fluid"))
            decl += [f.declaration for f in self.tube.forces]  # e.g. the shock capturing's heating breaks parcel_entropy
            if self.tube.has_wall:
                decl.append(Declaration("wall"))
        return decl

    def invariants(self):
        """Invariants this model keeps, derived from its terms', forces' and ends' declarations."""
        if self.coupled and self.tube.open:
            # open ends (docs/theory.md §13.4): balanced against the fluxes through the ends and the supports' impulse
            return self.tube.invariants()
        if self.coupled:
            base = ["energy", "linear_momentum", "angular_momentum", "mass"]
            if self.tube.eos is not None and self.tube.eos.has_entropy:
                base.append("parcel_entropy")
            if self.tube.incompressible:
                base.append("parcel_volume")
            return derive_invariants(self.declarations(), base=base)
        if self.rod is not None:
            return derive_invariants(self.rod.declarations())
        return self.tube.invariants()

    def describe(self):
        """Dictionary for ``varint check``: effects, unknowns, invariants, resolved numbers."""
        d = self.rod.describe() if self.rod is not None else self.tube.describe()
        if self.coupled:
            td = self.tube.describe()
            d["effects"] = self.scene.effects
            d["unknowns"] = {name: int(np.size(np.arange(self.nz)[idx])) for name, idx in self.layout.items()}
            d["unknowns_total"] = self.nz
            d["inertial_unknowns"] = self.nz - self.tube.nlam - self.rod.nlam
            d["algebraic_unknowns"] = self.tube.nlam + self.rod.nlam
            d["terms"] = d["terms"] + td["terms"] + ["fluid_kinetic", "fluid_potential"]
            d["invariants"] = self.invariants()
            d["lattice"]["parcels"] = self.tube.M
            for k in ("wall", "fluid"):
                if k in td:
                    d[k] = td[k]
        d["scheme"] = self.scheme
        return d


def build_model(scene):
    """Assemble the :class:`Model` of a validated scene.

    Problems only visible once fields are evaluated (a perturbation that makes
    a radius or density non-positive) are reported as :class:`SceneError`.
    """
    try:
        return Model(scene)
    except ValueError as exc:
        raise SceneError(str(exc), source=scene.path) from None
