"""What a level of a run holds: the monitors (energies, momenta, mass, constraint residuals) and the fields of a
state, for the straight tube, the rod alone and the coupled tube (docs/theory.md §4, §9, §10.5-§10.6; docs/output.md).

The energy of a variational scheme is that of its discrete action (:class:`varint.schemes.midpoint.Step`): the
level energy H(q_n, p_n) where every unknown carries inertia, else the energy of the step that ended at the level.
A stepper mixes :class:`LevelMonitors` in and provides ``model``, ``state``, ``h`` and ``action`` (the Step).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..lattice.lie import cay
from ..terms.coupled import element_strains, kinetic_metric_of, stretched_volumes_of
from ..terms.rod import unpack_level
from ..terms.rod_constraint import constraint_jacobian, element_strain_residual

__all__ = ["LevelMonitors"]


class LevelMonitors:
    """Monitors and fields of the current level ``self.state`` (a mixin of the steppers)."""

    @property
    def open(self):
        """True for the straight tube with open ends (docs/theory.md §13)."""
        t = self.model.tube
        return t is not None and getattr(t, "open", False)

    def monitors(self):
        """Invariants and energies at the current level (each part's, summed where they add up)."""
        if self.open:
            return self._oc_monitors() if self.model.coupled else self._open_monitors()
        if self.model.coupled:
            return self._coupled_monitors()
        # one part: the tube's blocks on the fixed centreline, or the rod alone
        out = self._tube_monitors() if self.model.tube is not None else self._rod_monitors()
        return out

    def _tube_monitors(self):
        """The tube's energies, mass, axial momentum, entropy and constraint.

        Energy: without algebraic unknowns, H(q_n, p_n) = 1/2 p M^-1 p + U(q_n) at the level (exactly
        conserved by the midpoint rule on linear problems, whatever h); with them (quasistatic wall,
        incompressible fluid) the energy of the step that ended here, 1/2 v M v + U(midpoint), because
        their half-level unknowns have no value at a level.  Record 0: the initial data.
        """
        m, st = self.model, self.state
        t = m.tube
        q, p, v_st = st.q[m.tube_q], st.p[m.tube_p], st.v[m.tube_p]
        out = {}
        if t.nlam == 0 or st.q_prev is None:
            pot = t.energies(t.config(np.concatenate([q, st.lam[m.tube_lam]])))
            v = p / np.where(t.mass > 0, t.mass, 1.0) if st.q_prev is not None else v_st
        else:
            pot = self.action.step_energies(st.q_prev, np.concatenate([q, st.lam[m.tube_lam], np.zeros(m.nz - m.tube_z.stop)]))
            v = v_st
        kin = 0.5 * t.mass * v * v
        kf = float(np.sum(kin[t.layout["s"]])) if "s" in t.layout else 0.0
        kw = float(np.sum(kin[t.layout["R"]])) if t.wall_dynamic else 0.0
        out["kinetic_energy"] = kf + kw
        out["energy_fluid_kinetic"] = kf
        out["energy_wall_kinetic"] = kw
        for k, val in pot.items():
            out[f"energy_{k}"] = val
        out["energy"] = out["kinetic_energy"] + sum(pot.values())
        # the mass the state holds: density field times the parcel volumes of the configuration (for an
        # incompressible fluid at the step's midpoint, where its volume constraint is imposed)
        out["mass"] = t.fluid_mass(self._mass_config()) if t.has_fluid else 0.0
        mom = np.zeros(3)
        if "s" in t.layout:
            mom[0] = float(np.sum(p[t.layout["s"]]))
        out["linear_momentum"] = mom
        # every fluid label moves along the x axis through the origin: r x p = 0
        out["angular_momentum"] = np.zeros(3)
        if t.has_fluid:
            out["entropy"] = float(np.sum(t.m * t.S))
            if t.incompressible:
                out["constraint_residual"] = float(np.max(np.abs(t.volumes(self._mass_config()) / t.V0 - 1.0)))
        return out

    def _mass_config(self):
        """The tube's configuration at the level, or at the last step's midpoint for an incompressible fluid."""
        m, st = self.model, self.state
        t = m.tube
        q = st.q[m.tube_q]
        if t.incompressible and st.q_prev is not None:
            q = 0.5 * (q + st.q_prev[m.tube_q])
        return t.config(np.concatenate([q, st.lam[m.tube_lam]]))

    def _rod_monitors(self):
        """The rod's level energy H(q_n, pi_n), momenta about the origin and the centre of mass, frames."""
        m, st = self.model, self.state
        rod = m.rod
        N = rod.N
        Lam, r, origin = unpack_level(st.q[m.rod_q], N)
        pp = st.p[m.rod_p]
        # supported components carry reaction impulses in D2 L_d, not momentum: leave them out
        p = pp[: 3 * (N + 1)].reshape(N + 1, 3) * rod.mask[:, :3]
        Pi = pp[3 * (N + 1):].reshape(N + 1, 3) * rod.mask[:, 3:]
        if rod.constrained:
            # the level momenta D2 L_d' lack the level's constraint impulse h ds G^T lambda^n (no motion, but
            # not tangent either): the kinetic energy is that of their part tangent to the constraint (p - G^T mu with
            # G M^-1 (p - G^T mu) = 0, the projection of RATTLE)
            p, Pi = self._tangent_momenta(Lam, r, p, Pi)
        pot = rod.level_energy(Lam, r, p, Pi, origin)
        out = {"kinetic_energy": pot.pop("kinetic")}
        for k, v in pot.items():
            out[f"energy_{k}"] = v
        out["energy"] = out["kinetic_energy"] + sum(pot.values())
        out["mass"] = float(np.sum(rod.node_mass))
        out["linear_momentum"] = p.sum(0)
        # about the (fixed) origin: origin x P + sum (r - origin) x p + Lambda Pi, each part from O(L) numbers
        spin = np.einsum("nij,nj->i", Lam, Pi)
        out["angular_momentum"] = np.cross(origin, p.sum(0)) + np.cross(r, p).sum(0) + spin
        # about the centre of mass: the well-conditioned one for a rod far from the origin (there the
        # difference angular_momentum - r_c x P cancels large numbers)
        out["angular_momentum_cm"] = np.cross(r - rod.centre_of_mass(r), p).sum(0) + spin
        out["frame_orthogonality"] = float(np.max(np.abs(np.swapaxes(Lam, 1, 2) @ Lam - np.eye(3))))
        if rod.constrained:

            out["rod_constraint_residual"] = element_strain_residual(rod, Lam, r)
        return out

    def _tangent_momenta(self, Lam, r, p, Pi):
        """The momenta's part tangent to Gamma = chi at the level, in the kinetic metric (reference measure)."""

        rod = self.model.rod
        mask = rod.mask
        G = constraint_jacobian(Lam, r, rod.ds, rod.ncomp, mask)
        minv = np.concatenate([np.repeat(1.0 / rod.node_mass[:, None], 3, axis=1),
                               1.0 / rod.node_inertia], axis=1)[mask]
        pa = np.concatenate([p, Pi], axis=1)[mask]
        A = (G @ sp.diags(minv) @ G.T).tocsc()
        mu = spla.spsolve(A, G @ (minv * pa)) if A.shape[0] else np.zeros(0)
        full = np.zeros((rod.N + 1, 6))
        full[mask] = pa - G.T @ mu
        return full[:, :3], full[:, 3:]

    def _coupled_levels(self):
        """(level-n configuration of the tube, rod frames, positions, origin) at the current level."""
        m, st = self.model, self.state
        t = m.tube
        cfg = t.config(np.concatenate([st.q[m.tube_q], st.lam[m.tube_lam]]))
        Lam, r, origin = unpack_level(st.q[m.rod_q], m.N)
        return cfg, Lam, r, origin

    def _coupled_volumes(self, cfg, Lam, r):
        """The parcels' stretched volumes at one level (docs/theory.md §10.3)."""
        t = self.model.tube
        return stretched_volumes_of(cfg.s, cfg.R, element_strains(Lam, r, t.ds)[0], t.ds, t.periodic)

    def _coupled_monitors(self):
        """Energy, momenta, mass and entropy of the coupled tube (docs/theory.md §10.5, §10.6).

        Energy: the fluid's kinetic metric depends on the labels, so the energy is that of the step that ended
        at this level, E = K(step) + U(midpoint data) = 2 K(step) - L_d / h, with K(step) the kinetic terms'
        share of L_d over h; record 0: the initial data's kinetic energy (the Legendre map of
        :meth:`varint.model.model.Model.initial_legendre`) plus the potential at the level.  Momenta: the full nodal
        momenta (they carry the fluid's, §10.6) about the origin and the centre of mass of rod and fluid.
        """
        m, st, h = self.model, self.state, self.h
        t, rod = m.tube, m.rod
        N = rod.N
        cfg, Lam, r, origin = self._coupled_levels()
        sch = self.action
        fluid = next(x for x in sch.terms if x.name == "fluid")
        out = {}
        if t.nlam == 0 or st.q_prev is None:
            # the level energy H(q_n, p_n): kinetic from the momenta through the kinetic metric, potential at the level
            Kf, Kr, Kw = self._coupled_level_kinetic(cfg, Lam, r)
            z = sch.unknowns(st.q, st.q, st.lam)
            U = -sum(x.value(sch.point(st.q, z)) for x in sch.terms) / h
            o_ref = origin
        else:
            # with half-level unknowns (multipliers, quasistatic radii) the energy of the step that ended here
            z = sch.unknowns(st.q_prev, st.q, st.lam)
            pt = sch.point(st.q_prev, z)
            L = sum(x.value(pt) for x in sch.terms)
            Kf = fluid.kinetic_value(pt) / h
            kin = 0.5 * (rod.section.rhoA * np.sum((pt.r_1 - pt.r_n) ** 2, axis=1)
                         + np.sum(rod.section.inertia * pt.xi * pt.xi, axis=1)) / h ** 2
            if rod.paper_measure:  # the kernel weights each element's kinetic density by |Gammabar_e|
                Om0, Ga0 = rod.strains(pt.Lam_n, pt.r_n)
                Om1, Ga1 = rod.strains(pt.Lam_n @ cay(pt.xi), pt.r_1)
                mu_e = np.linalg.norm(0.5 * (Ga0 + Ga1), axis=1)
                Kr = float(np.sum(rod.ds * mu_e * 0.5 * (kin[:-1] + kin[1:])))
            else:
                Kr = float(np.sum(rod.w * kin))
            Kw = 0.5 * float(np.sum(t.mass * st.v[m.tube_p] ** 2)) if t.wall_dynamic else 0.0
            U = (Kf + Kr + Kw) - L / h
            o_ref = unpack_level(st.q_prev[m.rod_q], N)[2]
        # positions in L_d are relative to the floating origin of the step's level n: the potentials linear in r
        # (gravity, the tip force) take the origin's part here
        mbar = t.label_mass_all
        M_tot = float(np.sum(rod.node_mass) + np.sum(mbar))
        M_grav = M_tot
        if rod.paper_measure:  # the rod's gravitational mass is rho A sum_e ds |Gamma_e| at the evaluation point
            if t.nlam == 0 or st.q_prev is None:
                _, Ga = rod.strains(Lam, r)
            else:
                Om0, Ga0 = rod.strains(pt.Lam_n, pt.r_n)
                Om1, Ga1 = rod.strains(pt.Lam_n @ cay(pt.xi), pt.r_1)
                Ga = 0.5 * (Ga0 + Ga1)
            M_grav = float(rod.section.rhoA * np.sum(rod.ds * np.linalg.norm(Ga, axis=1)) + np.sum(mbar))
        U -= M_grav * float(np.dot(rod.g, o_ref)) + float(np.dot(rod.force, o_ref))
        out["kinetic_energy"] = Kf + Kr + Kw
        out["energy_fluid_kinetic"] = Kf
        out["energy_rod_kinetic"] = Kr
        out["energy_wall_kinetic"] = Kw
        out["energy_potential"] = U
        out["energy"] = Kf + Kr + Kw + U
        # mass from the state: density field times the stretched parcel volumes (incompressible: where the
        # constraint holds, at the level for a liquid held at the levels, else at the last step's midpoint)
        V = self._coupled_volumes(cfg, Lam, r)
        if t.incompressible and st.q_prev is not None and not fluid.level_constraint:
            s0, R0, s1, R1, _, Lam1 = fluid.levels(sch.point(st.q_prev, sch.unknowns(st.q_prev, st.q, st.lam)))
            Lp, rp, op = unpack_level(st.q_prev[m.rod_q], N)
            G0, _, _ = element_strains(Lp, rp + op - origin, t.ds)
            G1, _, _ = element_strains(Lam, r, t.ds)
            Vbar = stretched_volumes_of(0.5 * (s0 + s1), 0.5 * (R0 + R1), 0.5 * (G0 + G1), t.ds, t.periodic)
            out["mass"] = float(np.sum(rod.node_mass) + np.sum(t.m / t.V0 * Vbar))
            out["constraint_residual"] = float(np.max(np.abs(Vbar / t.V0 - 1.0)))
        else:
            rho = t.m / t.V0 if t.incompressible else t.m / V
            out["mass"] = float(np.sum(rod.node_mass) + np.sum(rho * V))
            if t.incompressible:
                out["constraint_residual"] = float(np.max(np.abs(V / t.V0 - 1.0)))
        pp = st.p[m.rod_p]
        p = pp[: 3 * (N + 1)].reshape(N + 1, 3) * rod.mask[:, :3]
        Pi = pp[3 * (N + 1):].reshape(N + 1, 3) * rod.mask[:, 3:]
        P = p.sum(0)
        spin = np.einsum("nij,nj->i", Lam, Pi)
        out["linear_momentum"] = P
        out["angular_momentum"] = np.cross(origin, P) + np.cross(r, p).sum(0) + spin
        X = m.centreline(cfg.s, r)[3]
        c = (np.sum(rod.node_mass[:, None] * r, axis=0) + np.sum(mbar[:, None] * X, axis=0)) / M_tot
        out["angular_momentum_cm"] = np.cross(r - c, p).sum(0) + spin
        out["frame_orthogonality"] = float(np.max(np.abs(np.swapaxes(Lam, 1, 2) @ Lam - np.eye(3))))
        if rod.constrained:

            out["rod_constraint_residual"] = element_strain_residual(rod, Lam, r)
        if t.eos is not None:
            out["entropy"] = float(np.sum(t.m * t.S))
        return out

    def _coupled_level_kinetic(self, cfg, Lam, r):
        """(fluid, rod, wall) kinetic energy 1/2 p.M(q)^-1.p at the level, from the discrete momenta.

        The kinetic metric of docs/theory.md §10.5: rho A w_j on the nodal velocities, the section inertia on
        the body angular velocities, a w_j on the radial ones, and the fluid's 1/2 sum_k mbar_k |Xdot_k|^2,
        Xdot_k = sum_i N_i(s_k) rdot_i + X'_k sdot_k, which couples nodes and labels.  Restricted to the
        unknowns that move (supported components and the closed ends' labels hold none).  The fluid's share
        is the energy of the labels' velocities Xdot that the solve gives.
        """

        m, st = self.model, self.state
        t, rod = m.tube, m.rod
        N, M = rod.N, t.M
        n1 = N + 1
        wmu = rod.w
        if rod.paper_measure:  # the rod's kinetic density is weighted by |Gamma_e| (RodPart.level_energy)
            _, Ga = rod.strains(Lam, r)
            mu = np.linalg.norm(Ga, axis=1)
            wmu = np.zeros(n1)
            wmu[:-1] += 0.5 * rod.ds * mu
            wmu[1:] += 0.5 * rod.ds * mu
        nodes, Nw, _, _, dX, _ = m.centreline(cfg.s, r)
        # variables: per node [rdot (3), body omega (3)], then the labels' sdot; Xdot_k = sum_a N_a rdot + X'_k sdot_k
        nvar = 6 * n1 + M + 1
        Mf, Jx = kinetic_metric_of(nodes, Nw, dX, t.label_mass_all, n1)
        rod_diag = np.concatenate([np.repeat((rod.section.rhoA * wmu)[:, None], 3, axis=1),
                                   rod.section.inertia[None, :] * wmu[:, None]], axis=1).ravel()
        Mt = Mf + sp.diags(np.concatenate([rod_diag, np.zeros(M + 1)]))
        labels = np.arange(M + 1)[m.free_labels]
        active = np.concatenate([np.nonzero(rod.mask.ravel())[0], 6 * n1 + labels])
        pr = st.p[m.rod_p].reshape(2, n1, 3).transpose(1, 0, 2).reshape(-1)
        ps = np.zeros(M + 1)
        ps[labels] = st.p[m.tube_p][t.layout["s"]]
        pa = np.concatenate([pr, ps])[active]
        Maa = Mt[active][:, active].tocsc()
        if rod.constrained:
            # the level momenta carry half the step's constraint impulse: keep their part tangent to Gamma = chi
            # in this metric (the saddle-point solve of RATTLE's projection)

            G = constraint_jacobian(Lam, r, rod.ds, rod.ncomp, rod.mask)
            G = sp.hstack([G, sp.csr_matrix((G.shape[0], len(active) - G.shape[1]))]).tocsr()
            K = sp.bmat([[Maa, G.T], [G, None]]).tocsc()
            va = spla.spsolve(K, np.concatenate([pa, np.zeros(G.shape[0])]))[: len(active)]
        else:
            va = spla.spsolve(Maa, pa) if len(pa) else np.zeros(0)
        vel = np.zeros(nvar)
        vel[active] = va
        Xdot = (Jx @ vel).reshape(M + 1, 3)
        Kf = 0.5 * float(np.sum(t.label_mass_all * np.sum(Xdot * Xdot, axis=1)))
        Kr = 0.5 * float(np.sum(rod_diag * vel[: 6 * n1] ** 2))
        Kw = 0.0
        if t.wall_dynamic:
            sl = t.layout["R"]
            pR = st.p[m.tube_p][sl]
            Kw = 0.5 * float(np.sum(pR * pR / t.mass[sl]))
        return Kf, Kr, Kw

    def fields(self):
        """Field values at the current level, keyed by HDF5 path under /fields."""
        if self.open:
            return self._oc_fields() if self.model.coupled else self._open_fields()
        m, st = self.model, self.state
        out = {}
        t = m.tube
        if m.coupled:
            cfg, Lam, r, origin = self._coupled_levels()
            V = self._coupled_volumes(cfg, Lam, r)
            rho = t.m / t.V0 if t.incompressible else t.m / V
            geo = m.centreline(cfg.s, r)
            out["fluid/s"] = cfg.s.copy()
            out["fluid/position"] = geo[3] + origin
            out["fluid/density"] = rho
            out["fluid/pressure"] = cfg.mu.copy() if t.incompressible else t.eos.pressure(rho, t.S)
            # the speed along the tube relative to it, |X'| ds/dt, of the last step (closed ends: 0)
            u = np.zeros(t.M + 1)
            u[m.free_labels] = st.v[m.tube_p][t.layout["s"]]
            if t.periodic:
                u[-1] = u[0]
            u *= np.linalg.norm(geo[4], axis=1)
            out["fluid/velocity"] = u
            out["fluid/entropy"] = t.S.copy()
            if t.has_wall:
                out["wall/R"] = t.full_radius(cfg)
                if t.wall_dynamic:
                    out["wall/velocity"] = st.v[m.tube_p][t.layout["R"]].copy()
            out["rod/r"] = r + origin
            out["rod/Lambda"] = Lam.copy()
            return out
        if t is not None:
            q = st.q[m.tube_q]
            cfg = t.config(np.concatenate([q, st.lam[m.tube_lam]]))
            if t.has_fluid:
                rho, p, u = t.fluid_fields(cfg, st.p[m.tube_p])
                out["fluid/s"] = cfg.s.copy()
                out["fluid/density"] = rho
                out["fluid/pressure"] = p
                out["fluid/velocity"] = u
                out["fluid/entropy"] = t.S.copy()
            if t.has_wall:
                out["wall/R"] = t.full_radius(cfg)
                if t.wall_dynamic:
                    vR = st.v[m.tube_p][t.layout["R"]]
                    out["wall/velocity"] = np.append(vR, vR[0]) if t.periodic else vR.copy()
        if m.rod is not None:
            Lam, r, origin = unpack_level(st.q[m.rod_q], m.N)
            out["rod/r"] = r + origin
            out["rod/Lambda"] = Lam.copy()
        return out
