"""The tube's blocks on the fixed straight centreline: fluid labels s, wall radii R, multipliers mu.

One part of the model (:mod:`varint.model.model`): the unknowns, masses and potential terms of the
``[fluid]`` and ``[wall]`` effects, present only when the scene has them.

Layout
------
*Configuration space* holds every lattice quantity a term can read:
``[s_0..s_M | R_0..R_{nR-1} | mu_0..mu_{M-1}]`` (blocks present only when
their effect is on).  *Unknowns* are what a step solves for:

``q`` (carry inertia, live at time levels)
    interior labels ``s`` (closed ends) or labels ``s_0..s_{M-1}`` (periodic);
    nodal radii ``R`` of a dynamic wall.
``lam`` (algebraic, live at half levels in the midpoint scheme)
    nodal radii of a quasistatic wall; pressure multipliers ``mu``.

``config = B @ concat(q, lam) + c0``; ``B`` is a constant sparse selection and
``c0`` holds the fixed end labels, the period shift and a rigid wall's radii.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp

from . import tube_potential as T
from .forces import Declaration, derive_invariants
from ..lattice.parcels import label_problem, parcel_volumes, radius_at
from ..scene.initial import initial_fields, shape_profile
from .thermo import make_eos
from ..scene.derived import wall_parameters

__all__ = ["TubePart"]


class TubePart:
    """Labels, radii and multipliers of a scene's ``[fluid]`` and ``[wall]``, with their masses and potential terms."""

    def __init__(self, scene):
        self.scene = scene
        tube = scene.tube
        self.L = tube.length
        self.N = tube.nodes - 1
        self.ds = self.L / self.N
        self.R0 = tube.radius
        self.has_wall = scene.wall is not None
        self.has_fluid = scene.fluid is not None
        self.periodic = self.has_fluid and scene.fluid.ends.s0 == "periodic"
        #: fluid.ends = { s0 = "inflow", sL = "outflow" } (docs/theory.md §13)
        self.open_ends = self.has_fluid and scene.fluid.ends.s0 == "inflow"
        self.nR = self.N if self.periodic else self.N + 1
        self.wall_dynamic = self.has_wall and scene.wall.model == "dynamic"
        self.incompressible = self.has_fluid and scene.fluid.model == "incompressible"
        self.scheme = scene.time.scheme
        self.eos = make_eos(scene.fluid) if self.has_fluid and not self.incompressible else None
        self.M = scene.fluid.parcels if self.has_fluid else 0
        self.wall = wall_parameters(scene.wall, self.R0) if self.has_wall else None
        self.p_ext = scene.environment.external_pressure
        self.gx = scene.environment.gravity[0]
        #: part of the coupled tube (docs/theory.md §10): the fluid's kinetic and potential terms and p_ext read
        #: the rod too and are step terms of the model (varint.terms.step.CoupledFluid); this part keeps the wall's
        self.coupled = scene.rod is not None
        #: non-conservative forces on the tube's blocks (discrete Lagrange-d'Alembert, varint.terms.forces.Force)
        self.forces = []
        #: open ends on the fixed straight centreline with a rigid wall (docs/theory.md §13): a varying set of labels
        #: (varint.terms.open_ends); with a [wall] (not yet) the closed layout is built and the stepper refuses the run
        if self.coupled:  # on a [rod]: an incompressible liquid in a rigid tube with a velocity inlet (§13.1, coupled)
            self.open = (self.open_ends and not self.has_wall and self.incompressible
                         and scene.fluid.ends.inflow == "velocity")
        else:
            self.open = self.open_ends and (not self.has_wall or self.wall_dynamic)
        if self.open:
            self._open_init()
        else:
            self._layout()
            self._initial_state()
            self._terms()
        #: [shock_capturing]: viscous pressure, energy-exact pressure and heating (varint.terms.shock_capturing)
        self.shock_capturing = None
        if getattr(scene, "shock_capturing", None) is not None and not self.open:
            if self.coupled:  # on a [rod]: the stretched volumes of the moving tube (bound to the model by Model)
                from .coupled_shock_capturing import CoupledShockCapturing

                self.shock_capturing = CoupledShockCapturing(self, scene.shock_capturing)
            else:
                from .shock_capturing import make_shock_capturing

                self.shock_capturing = make_shock_capturing(self, scene.shock_capturing)
            self.forces.append(self.shock_capturing)

    # -- layout -------------------------------------------------------------

    def _layout(self):
        M, nR = self.M, self.nR
        nlab = M + 1 if self.has_fluid else 0
        self.index = {"s": 0, "R": nlab, "mu": nlab + nR}
        self.nconfig = nlab + nR + (M if self.incompressible else 0)
        blocks = {}
        pos = 0
        if self.has_fluid:
            n = M if self.periodic else M - 1
            blocks["s"] = slice(pos, pos + n)
            pos += n
        if self.wall_dynamic:
            blocks["R"] = slice(pos, pos + nR)
            pos += nR
        self.nq = pos
        if self.has_wall and not self.wall_dynamic:
            blocks["R"] = slice(pos, pos + nR)
            pos += nR
        if self.incompressible:
            blocks["mu"] = slice(pos, pos + M)
            pos += M
        self.nz = pos
        self.nlam = self.nz - self.nq
        #: unknown blocks by name, slices into concat(q, lam)
        self.layout = blocks
        rows, cols = [], []
        if self.has_fluid:
            if self.periodic:
                lab = np.arange(M)
                rows += [lab, [M]]
                cols += [blocks["s"].start + lab, [blocks["s"].start]]
            else:
                lab = np.arange(1, M)
                rows.append(lab)
                cols.append(blocks["s"].start + lab - 1)
        if self.has_wall:
            rows.append(self.index["R"] + np.arange(nR))
            cols.append(blocks["R"].start + np.arange(nR))
        if self.incompressible:
            rows.append(self.index["mu"] + np.arange(M))
            cols.append(blocks["mu"].start + np.arange(M))
        r = np.concatenate([np.asarray(x, dtype=np.int64) for x in rows]) if rows else np.empty(0, np.int64)
        c = np.concatenate([np.asarray(x, dtype=np.int64) for x in cols]) if cols else np.empty(0, np.int64)
        self.B = sp.csr_matrix((np.ones(len(r)), (r, c)), shape=(self.nconfig, self.nz))
        self.c0 = np.zeros(self.nconfig)
        if self.has_fluid:
            if self.periodic:
                self.c0[M] = self.L
            else:
                self.c0[M] = self.L  # s_0 = 0 and s_M = L are fixed
        # trapezoidal weights of the nodal (lumped) wall terms
        w = np.full(nR, self.ds)
        if not self.periodic:
            w[0] = w[-1] = 0.5 * self.ds
        self.node_weights = w
        self.node_s = np.arange(nR) * self.ds

    @property
    def midpoint_terms(self):
        """The potential terms of the step's midpoint: all but a liquid held at the levels (the open straight tube's
        incompressibility is the OpenLevelConstraint step term's, varint.terms.open_ends)."""
        if getattr(self, "level_constraint", False) and self.open:
            return [x for x in self.terms if x.name != "incompressibility"]
        return self.terms

    @property
    def unknown_names(self):
        return list(self.layout)

    # -- open ends (docs/theory.md §13) ---------------------------------------------------

    def _open_init(self):
        """The open straight tube: the duct on the extended line, the inlet's parcel, the initial lattice on [0, L]."""
        from .open_ends import Duct, EndPressures

        sc = self.scene
        e = sc.fluid.ends
        self.inflow = e.inflow  #: "velocity" (the first label is a piston moving at U_in) or "pressure"
        self.U_in = float(e.inflow_velocity)
        self.p_in = float(e.inflow_pressure)
        self.p_out = float(e.outflow_pressure)
        self.n_fixed = 1 if self.inflow == "velocity" else 0  #: labels prescribed (data of L_d), upstream first
        self.nR = self.N + 1
        R = np.full(self.nR, self.R0)
        self.node_s = np.arange(self.nR) * self.ds
        if sc.tube.area_table is not None and not self.has_wall:
            tab = np.array(sc.tube.area_table)
            R = np.sqrt(np.interp(self.node_s, tab[:, 0], tab[:, 1]) / math.pi)
        if self.has_wall:
            for pert in sc.wall.perturbation:
                R = R + shape_profile(pert, self.node_s)
            if np.any(R <= 0):
                raise ValueError("wall.perturbation: makes the radius non-positive somewhere")
        self.R_reference = R
        w = np.full(self.nR, self.ds)
        w[0] = w[-1] = 0.5 * self.ds
        self.node_weights = w
        self.duct = Duct(R, self.ds)
        # the entering fluid: parcels of the scene's parcel length at the inlet section, at the inlet's state
        rho_in = float(e.inflow_density)
        if self.eos is not None and not self.eos.has_entropy and self.inflow == "pressure":
            rho_in = float(self.eos.density(self.p_in))  # a barotropic liquid's density follows from the inlet pressure
        self.rho_in = rho_in
        self.ell_in = self.L / self.M
        if self.has_wall:
            from .open_ends import ExtendedLattice

            # a dynamic wall (docs/theory.md §13.1): the kernels on the lattice extended beyond each end, far enough for
            # the labels of the end parcels (a label beyond it stops the run: "left the tube")
            self.ext = ExtendedLattice(self.N, self.ds, int(math.ceil(4.0 * self.ell_in / self.ds)) + 1)
        if self.coupled:
            from .open_ends import CoupledExtension

            # the coupled tube (docs/theory.md §13.1): the centreline continued straight beyond each end, far enough
            # for the end parcels' labels and the Catmull-Rom stencil around them
            self.ext = CoupledExtension(self.N, self.ds, int(math.ceil(2.0 * self.ell_in / self.ds)) + 2)
        self.V_in = self.duct.A_in * self.ell_in
        #: the volume flux of a velocity inlet through the inlet section: the piston moves so that it sweeps Q_in per
        #: unit time wherever it is, F(s_0^{n+1}) = F(s_0^n) + h Q_in (docs/theory.md §13.8)
        self.Q_in = self.U_in * self.duct.A_in
        #: the piston's velocity over the last step (the released piston keeps it; t = 0: the inlet's)
        self.piston_velocity = self.U_in
        #: an incompressible liquid on the straight tube is held at the levels (SHAKE; varint.terms.open_ends
        #: OpenLevelConstraint, docs/theory.md §13.8): its pressures act at level n, the end forces with them
        self.level_constraint = self.incompressible and not self.coupled
        #: the share of level n's impulses that a step takes: 1/2 in the first step (OpenLevelConstraint), else 1
        self.level_weight = 1.0
        # the outlet (docs/theory.md §13.9): a pressure, a non-reflecting (characteristic) impedance, or an R-C-R windkessel
        self.outflow = getattr(e, "outflow", "pressure") or "pressure"
        self.u_ref = float(sc.fluid.velocity)
        self.Z_out = self._characteristic_impedance()
        self.windkessel = (None if self.outflow != "windkessel" else
                           (float(e.windkessel_R1), float(e.windkessel_C), float(e.windkessel_R2)))
        #: the windkessel's capacitor pressure (state data); t = 0: the fluid's pressure
        self.p_c = float(sc.fluid.pressure) if sc.fluid.pressure is not None else self.p_ext
        self.m_in = rho_in * self.V_in
        self.S_in = float(self.eos.entropy(rho_in, self.p_in)) if self.eos is not None and self.eos.has_entropy else 0.0
        self.rho0 = sc.fluid.density
        #: label slots of the run file (fixed): the tube holds at most this many parcels (a gas compressed twofold)
        self.M_max = 2 * self.M + 8
        f = initial_fields(sc.fluid, self.eos)
        s = np.linspace(0.0, self.L, self.M + 1)
        V = self.duct.volumes(s)
        centres = 0.5 * (s[:-1] + s[1:])
        self.m = f.density(centres) * V
        self.S = f.entropy(centres)
        u = f.velocity(s)
        if self.incompressible and not self.coupled and not self.duct.uniform:
            # a liquid in a duct of varying section: the only velocities its volumes allow carry one volume flux,
            # u(s) A(s) = u A(0) (a uniform u would be projected by the first step: docs/theory.md §13.8)
            u = u * self.duct.A_in / self.duct.A(s)
        self.piston = float(s[0])  #: the prescribed first label's position at the level (velocity inlet)
        #: the ends' rule (docs/theory.md §13.2-13.3): a rigid tube holds the parcels whose centres are in it; a dynamic
        #: wall's is kept full (the first label at or before s = 0, the last at or beyond L: no wall without fluid)
        self.filled = self.has_wall
        #: accumulated balances: E0, P0, mass0 (set by the stepper at t = 0), then the boundary fluxes of energy,
        #: axial momentum and mass summed over the run (docs/theory.md §13.4)
        self.balance = np.zeros(6)
        self.lattice_version = 0
        # the coupled tube's liquid works with gauge pressures p - p_ext (its multipliers; the kernels' p_ext is 0): a free
        # jet at the outlet then carries no end force
        self.forces = [] if self.coupled else [EndPressures(self)]
        self.terms = []
        self._open_build()
        nf = self.n_fixed
        zR = np.zeros(self.nR - 2 if self.has_wall else 0)  # the interior radii: displacements from R_reference
        self.q_init = np.concatenate([s[nf:], zR])
        self.v_init = np.concatenate([u[nf:], zR])
        self.p_init = self.mass * self.v_init
        self.lam_init = np.full(self.M, float(sc.fluid.pressure)) if self.incompressible else np.zeros(0)
        if self.coupled:
            self.lam_init = self.lam_init - self.p_ext
            self.p_init = np.zeros_like(self.q_init)  # the Legendre map of the coupled tube (varint.model.model)

    def _characteristic_impedance(self):
        """rho c of the scene's fluid state at the outlet, c the long-wave speed with the wall's compliance,
        1/c^2 = 1/c0^2 + (rho/A) dA/dp (docs/theory.md §6 at k -> 0): 4 pi rho / beta2 for the linear wall, 2 rho / beta
        for the tube law; inf for a liquid in a rigid tube (no waves)."""
        sc = self.scene
        rho = float(sc.fluid.density)
        inv_c2 = 0.0
        if self.eos is not None:
            S = self.eos.entropy(rho, sc.fluid.pressure) if self.eos.has_entropy else None
            inv_c2 = 1.0 / float(self.eos.sound_speed(rho, S)) ** 2
        if self.has_wall:
            w = self.wall
            inv_c2 += 4.0 * math.pi * rho / w.beta2 if w.law == "linear" else 2.0 * rho / w.stiffness
        return rho / math.sqrt(inv_c2) if inv_c2 > 0.0 else math.inf

    def piston_after(self, h):
        """The velocity inlet's piston one step of ``h`` after its level position: it sweeps the volume h Q_in of the
        duct (docs/theory.md §13.8; in the inlet's section, where a dynamic wall's tube keeps it, U_in h)."""
        if self.filled or self.duct.uniform or self.coupled:
            return self.piston + h * self.U_in
        key = (self.piston, h)
        if getattr(self, "_piston_after", (None, None))[0] != key:
            self._piston_after = (key, float(self.duct.above(self.piston, h * self.Q_in)))
        return self._piston_after[1]

    def coupled_rebase(self, V):
        """The coupled tube's parcels at t = 0 hold their stretched volumes ``V`` on the rod's initial centreline (so the
        constraints hold at the start): masses rho V."""
        self.m = self.rho0 * np.asarray(V, dtype=float)
        self._open_build()

    def label_masses(self, m=None):
        """Lumped label masses of an open lattice: (m_{k-1} + m_k)/2 inside, half a parcel at each end."""
        m = self.m if m is None else m
        return np.concatenate([[0.5 * m[0]], 0.5 * (m[:-1] + m[1:]), [0.5 * m[-1]]])

    def _open_build(self):
        """Layout, B, c0, masses and terms of the current open lattice (labels 0..M, the first n_fixed prescribed)."""
        from .open_ends import OpenIncompressibility, OpenInternalEnergy, WallIncompressibility, WallInternalEnergy

        self.M = M = len(self.m)
        nf, nR = self.n_fixed, self.nR
        nlab = M + 1
        self.index = {"s": 0, "R": nlab, "mu": nlab + nR}
        self.nconfig = nlab + nR + (M if self.incompressible else 0)
        ns = nlab - nf
        # a dynamic wall's end nodes are held at the reference radius (the tube is fitted to rigid pipes at its open
        # ends): only the interior radii are unknowns
        self.nq = ns + (nR - 2 if self.has_wall else 0)
        blocks = {"s": slice(0, ns)}
        if self.has_wall:
            blocks["R"] = slice(ns, ns + nR - 2)
        if self.incompressible:
            blocks["mu"] = slice(self.nq, self.nq + M)
        self.nz = self.nq + (M if self.incompressible else 0)
        self.nlam = self.nz - self.nq
        self.layout = blocks
        rows = [np.arange(nf, nlab)]
        cols = [np.arange(ns)]
        if self.has_wall:
            rows.append(self.index["R"] + np.arange(1, nR - 1))
            cols.append(ns + np.arange(nR - 2))
        if self.incompressible:
            rows.append(self.index["mu"] + np.arange(M))
            cols.append(self.nq + np.arange(M))
        r, c = np.concatenate(rows), np.concatenate(cols)
        self.B = sp.csr_matrix((np.ones(len(r)), (r, c)), shape=(self.nconfig, self.nz))
        self.c0 = np.zeros(self.nconfig)
        self.c0[self.index["R"]:self.index["R"] + nR] = self.R_reference
        if nf:
            self.c0[0] = self.piston  # the stepper puts the step's midpoint here while it solves
        mb = self.label_masses()
        self.label_mass_config = mb
        self.label_mass_all = mb
        self.mass = mb[nf:].copy()
        if self.coupled:  # the labels' kinetic energy is the coupled term's (varint.terms.step.CoupledFluid)
            self.mass[:] = 0.0
            self.V0 = self.m / self.rho0
            self.terms = []
            self.lattice_version += 1
            return
        if self.has_wall:
            self.mass = np.concatenate([self.mass, self.wall.a * self.node_weights[1:-1]])
        if self.incompressible:
            self.V0 = self.m / self.rho0
            self.terms = [WallIncompressibility(self.ext, self.V0) if self.has_wall
                          else OpenIncompressibility(self.duct, self.V0)]
        else:
            self.terms = [WallInternalEnergy(self.ext, self.eos, self.m, self.S) if self.has_wall
                          else OpenInternalEnergy(self.duct, self.eos, self.m, self.S)]
        if self.has_wall:  # the wall's own terms on the real nodes (varint.terms.tube_potential), as on a closed tube
            w = self.wall
            if w.law == "linear":
                self.terms.append(T.WallLinear(self.ds, self.node_weights, False, w.beta1, w.beta2, self.R0))
            else:
                self.terms.append(T.WallTubeLaw(self.ds, self.node_weights, False, w.stiffness, w.tension, self.R0))
            if self.p_ext != 0.0:
                self.terms.append(T.ExternalPressure(self.ds, False, self.p_ext))
        self.lattice_version += 1

    def duct_at(self, R):
        """The duct of nodal radii ``R`` (the rigid tube's own; a dynamic wall's at a level)."""
        from .open_ends import Duct

        return Duct(R, self.ds) if self.has_wall else self.duct

    def active_mask(self):
        """Which of the M_max + 1 label slots hold a label (slot k: the k-th label from the upstream end)."""
        a = np.zeros(self.M_max + 1, dtype=np.int64)
        a[: self.M + 1] = 1
        return a

    # -- data the forces change (State.data, checkpoints) ------------------------------

    def evolving_data(self):
        """``{"S": parcel entropies}`` when a viscosity heats the parcels ([shock_capturing]), else ``{}``.

        Open ends: the lattice (parcel masses ``m``, entropies ``S``, the ``piston`` position, the ``active`` slot
        mask) and the accumulated ``balance`` (docs/theory.md §13.4-13.5): what a resumed run rebuilds from.
        """
        if self.open:
            d = {"m": self.m.copy(), "S": self.S.copy(), "piston": np.array([self.piston]),
                 "balance": self.balance.copy(), "active": self.active_mask().astype(float)}
            if not self.coupled:
                d["inlet_outlet"] = np.array([self.piston_velocity, self.p_c])
            return d
        return {"S": self.S.copy()} if self.shock_capturing is not None else {}

    def set_evolving_data(self, data):
        """Restore :meth:`evolving_data` (in place: the internal-energy term holds this array)."""
        if self.open:
            if not data or "m" not in data:
                return
            m, S = np.asarray(data["m"], dtype=float), np.asarray(data["S"], dtype=float)
            self.piston = float(data["piston"][0])
            self.balance = np.array(data["balance"], dtype=float)
            if "inlet_outlet" in data:
                self.piston_velocity, self.p_c = (float(x) for x in data["inlet_outlet"])
            if len(m) != len(self.m) or np.any(m != self.m) or np.any(S != self.S):
                self.m, self.S = m.copy(), S.copy()
                self._open_build()
            elif self.n_fixed:
                self.c0[0] = self.piston
            return
        if self.shock_capturing is not None and data and "S" in data:
            self.S[:] = data["S"]

    # -- initial state ------------------------------------------------------

    def _initial_state(self):
        sc = self.scene
        R_init = np.full(self.nR, self.R0)
        if not self.has_wall and sc.tube.area_table is not None:
            tab = np.array(sc.tube.area_table)
            R_init = np.sqrt(np.interp(self.node_s, tab[:, 0], tab[:, 1]) / math.pi)
        if self.has_wall:
            for p in sc.wall.perturbation:
                R_init = R_init + shape_profile(p, self.node_s)
            if np.any(R_init <= 0):
                raise ValueError("wall.perturbation: makes the radius non-positive somewhere")
        self.R_reference = R_init.copy()
        # Unknowns are displacements from the reference lattice (c0 holds the reference): the
        # round-off of a step then scales with the motion, not with the absolute position, which
        # keeps momentum maps conserved to the Newton tolerance on long tubes.
        self.c0[self.index["R"]:self.index["R"] + self.nR] = R_init
        q = np.zeros(self.nq)
        lam = np.zeros(self.nlam)
        v = np.zeros(self.nq)
        self.m = np.zeros(self.M)
        self.S = np.zeros(self.M)
        if self.has_fluid:
            f = initial_fields(sc.fluid, self.eos)
            s = np.linspace(0.0, self.L, self.M + 1)
            V = parcel_volumes(s, R_init, self.ds, self.periodic)
            centres = 0.5 * (s[:-1] + s[1:])
            rho, S, u_lab = f.density(centres), f.entropy(centres), f.velocity(s)
            self.m = rho * V
            self.S = S
            self.V0 = V.copy()
            self.rho0 = sc.fluid.density
            sl = self.layout["s"]
            self.c0[: self.M] = s[:-1]  # with c0[M] = L from the layout: labels at rest positions
            if self.periodic:
                v[sl] = u_lab[:-1]
            else:
                v[sl] = u_lab[1:-1]
            if self.incompressible:
                lam[self.layout["mu"].start - self.nq:] = sc.fluid.pressure
            ts = getattr(sc.fluid, "traveling_shock", None)
            if ts is not None and self.wall_dynamic:
                # [initial.traveling_shock]: the wall moves with the wave, dR/dt = -c dR/dx
                v[self.layout["R"]] = ts.wave.wall_velocity(self.node_s - ts.position)[: self.nR]
        self.mass = self._mass_vector()
        self.q_init, self.lam_init, self.v_init = q, lam, v
        self.p_init = self.mass * v

    def _mass_vector(self):
        mass = np.zeros(self.nq)
        if self.has_fluid:
            m = self.m
            lab = 0.5 * (np.roll(m, 1) + m)  # label k between parcels k-1 and k
            self.label_mass_config = np.zeros(self.M + 1)
            if self.periodic:
                mass[self.layout["s"]] = lab
                self.label_mass_config[:-1] = lab
            else:
                mass[self.layout["s"]] = lab[1:]
                self.label_mass_config[1:-1] = lab[1:]
            #: label masses of every label, the closed ends' included (m_0/2, m_{M-1}/2): on the coupled tube the
            #: end labels move with the rod's end nodes and keep their kinetic energy (docs/theory.md §10.1)
            self.label_mass_all = np.concatenate([[0.5 * m[0]], 0.5 * (m[:-1] + m[1:]), [0.5 * m[-1]]])
            if self.periodic:  # label M is label 0 shifted by the period: counted once, at label 0
                self.label_mass_all = np.concatenate([[0.5 * (m[-1] + m[0])], 0.5 * (m[:-1] + m[1:]), [0.0]])
            if self.coupled:  # the labels' kinetic energy is the coupled term's, not a diagonal mass
                mass[self.layout["s"]] = 0.0
        if self.wall_dynamic:
            mass[self.layout["R"]] = self.wall.a * self.node_weights
        return mass

    # -- terms --------------------------------------------------------------

    def _terms(self):
        terms = []
        uniform_rigid = not self.has_wall and self.scene.tube.area_table is None
        geom = (self.ds, self.periodic, self.has_wall)
        if self.has_fluid and not self.coupled:
            if self.incompressible:
                terms.append(T.Incompressibility(geom, self.V0, uniform_rigid))
            else:
                terms.append(T.InternalEnergy(geom, self.eos, self.m, self.S, uniform_rigid))
            if self.gx != 0.0:
                terms.append(T.Gravity(self.label_mass_config, self.gx))
        if self.has_wall:
            w = self.wall
            if w.law == "linear":
                terms.append(T.WallLinear(self.ds, self.node_weights, self.periodic, w.beta1, w.beta2, self.R0))
            else:
                terms.append(T.WallTubeLaw(self.ds, self.node_weights, self.periodic, w.stiffness, w.tension, self.R0))
            if self.p_ext != 0.0 and not self.coupled:
                terms.append(T.ExternalPressure(self.ds, self.periodic, self.p_ext))
        self.terms = terms

    def invariants(self):
        """Invariants this model keeps, from the terms' declarations and the boundaries.

        Open ends (docs/theory.md §13.4): energy, axial momentum and mass are not kept but balanced against the
        boundary fluxes (``energy_balance``, ``momentum_balance``, ``mass_balance``); an incompressible liquid
        keeps its parcels' volumes.
        """
        if self.open:
            return ["energy_balance", "momentum_balance", "mass_balance"] + (["parcel_volume"] if self.incompressible else [])
        base = ["energy"]
        if self.has_fluid:
            base += ["mass", "parcel_entropy"] if self.eos is not None and self.eos.has_entropy else ["mass"]
            if self.periodic:  # closed ends hold the fluid: only a periodic tube can keep its axial momentum
                base.append("axial_momentum")
        if self.incompressible:
            base.append("parcel_volume")
        # the same rule as the rod's (varint.terms.forces): a term's `breaks` removes what it names
        decl = [Declaration(t.name, {b: None for b in t.breaks}) for t in self.terms]
        decl += [f.declaration for f in self.forces]  # e.g. a viscosity heating the parcels breaks parcel_entropy
        return derive_invariants(decl, base=base)

    # -- configuration and potential ----------------------------------------

    def config(self, z):
        """Configuration (s, R, mu) from the unknown vector z = concat(q, lam)."""
        c = self.B @ z + self.c0
        i = self.index
        s = c[: i["R"]]
        R = c[i["R"]: i["R"] + self.nR]
        mu = c[i["mu"]:] if self.incompressible else None
        return T.Config(s, R, mu)

    def label_problem(self, cfg):
        """``(k, text)`` naming the first label that folds the lattice or leaves the tube, or None.

        Closed tubes: labels inside ``[0, L]`` and strictly increasing; periodic tubes: strictly
        increasing over one period (see :func:`varint.lattice.parcels.label_problem`).
        """
        if not self.has_fluid:
            return None
        if self.open:  # the extended line: finite, increasing labels (a wall's: within its extended lattice)
            if self.has_wall or self.coupled:
                return label_problem(cfg.s + self.ext.shift, self.nR + 2 * self.ext.E, self.ds, False)
            return label_problem(cfg.s, self.nR, self.ds, False, tube=False)
        return label_problem(cfg.s, self.nR, self.ds, self.periodic)

    def energies(self, cfg):
        """Each potential term's value (the multiplier term is left out: it vanishes on the constraint).

        NaN for every term when the labels are outside the lattice's domain (:meth:`label_problem`).
        """
        cache = {}
        bad = self.label_problem(cfg) is not None
        return {t.name: (math.nan if bad else t.energy(cfg, cache)) for t in self.terms if t.name != "incompressibility"}

    def potential(self, cfg, terms=None):
        if self.label_problem(cfg) is not None:
            return math.nan
        cache = {}
        return sum(t.energy(cfg, cache) for t in (self.terms if terms is None else terms))

    def gradient(self, cfg, terms=None):
        """Gradient of the potential in configuration index space.

        All NaN when the labels fold or leave the tube: a Newton iterate there has a non-finite
        residual, which fails the step cleanly instead of evaluating the kernels outside their domain.
        """
        if self.label_problem(cfg) is not None:
            return np.full(self.nconfig, np.nan)
        gs = np.zeros(self.index["R"])
        gR = np.zeros(self.nR)
        gmu = np.zeros(self.M if self.incompressible else 0)
        cache = {}
        for t in (self.terms if terms is None else terms):
            t.gradient(cfg, cache, gs, gR, gmu)
        return np.concatenate([gs, gR, gmu])

    def hessian(self, cfg, terms=None):
        """Hessian of the potential in configuration index space (CSR); NaN on the diagonal when the labels are invalid."""
        if self.label_problem(cfg) is not None:
            return sp.diags(np.full(self.nconfig, np.nan)).tocsr()
        cache = {}
        parts = [t.hessian(cfg, cache, self.index) for t in (self.terms if terms is None else terms)]
        r = np.concatenate([p[0] for p in parts]) if parts else np.empty(0, np.int64)
        c = np.concatenate([p[1] for p in parts]) if parts else np.empty(0, np.int64)
        v = np.concatenate([p[2] for p in parts]) if parts else np.empty(0)
        return sp.csr_matrix((v, (r, c)), shape=(self.nconfig, self.nconfig))

    # -- observables ----------------------------------------------------------

    def volumes(self, cfg):
        if self.open:
            return self.terms[0].volumes(cfg, {})
        return parcel_volumes(cfg.s, cfg.R, self.ds, self.periodic)

    def density(self, cfg, V=None):
        """Density of each parcel in configuration ``cfg``.

        Compressible fluid: ``m_k / V_k`` with ``V_k`` the parcel volume of ``cfg`` (the density the
        equation of state sees).  Incompressible fluid: the parcel's own constant density
        ``m_k / V0_k`` (its volume is constrained, the density is not derived from it).
        """
        if self.incompressible:
            return self.m / self.V0
        return self.m / (self.volumes(cfg) if V is None else V)

    def fluid_mass(self, cfg):
        """``sum_k rho_k V_k``: the density field of :meth:`density` integrated over the parcel volumes of ``cfg``.

        Evaluated from the state, not from the parcel masses: for an incompressible fluid it measures the
        volume constraint (``rho0 sum_k V_k``), for a compressible one it checks that the density field
        and the configuration's volumes agree.
        """
        V = self.volumes(cfg)
        return float(np.sum(self.density(cfg, V) * V))

    def fluid_fields(self, cfg, p_q):
        """Density, pressure (parcels) and velocity (labels) at one time level."""
        V = self.volumes(cfg)
        rho = self.density(cfg, V)
        if self.incompressible:
            pressure = cfg.mu.copy()
        else:
            pressure = self.eos.pressure(rho, self.S)
        u = np.zeros(self.M + 1)
        sl = self.layout["s"]
        vel = p_q[sl] / self.mass[sl]
        if self.periodic:
            u[:-1] = vel
            u[-1] = vel[0]
        else:
            u[1:-1] = vel
        return rho, pressure, u

    def full_radius(self, cfg):
        """Nodal radii 0..N (the periodic node N repeats node 0)."""
        return np.append(cfg.R, cfg.R[0]) if self.periodic else cfg.R.copy()

    def radius_at(self, x, cfg):
        return radius_at(x, cfg.R, self.ds, self.periodic)

    def describe(self):
        """Dictionary for ``varint check``: effects, unknowns, invariants, resolved numbers."""
        d = {
            "effects": self.scene.effects,
            "unknowns": {name: sl.stop - sl.start for name, sl in self.layout.items()},
            "unknowns_total": self.nz,
            "inertial_unknowns": self.nq,
            "algebraic_unknowns": self.nlam,
            "terms": [t.name for t in self.terms],
            "forces": [f.declaration.name for f in self.forces],
            "invariants": self.invariants(),
            "scheme": self.scheme,
            "lattice": {"elements": self.N, "ds": self.ds, "parcels": self.M, "periodic": self.periodic},
        }
        if self.wall is not None:
            d["wall"] = {k: getattr(self.wall, k) for k in ("law", "a", "beta1", "beta2", "stiffness", "tension")}
        if self.has_fluid:
            d["fluid"] = {"model": self.scene.fluid.model, "total_mass": float(np.sum(self.m)),
                          "external_pressure": self.p_ext}
        if self.open:
            d["open_ends"] = {"inflow": self.inflow, "inflow_velocity": self.U_in, "inflow_density": self.rho_in,
                              "inflow_pressure": self.p_in, "outflow_pressure": self.p_out,
                              "inflow_parcel_length": self.ell_in, "inflow_parcel_mass": self.m_in,
                              "parcel_slots": self.M_max}
        return d
