"""Open ends in time (docs/theory.md §13.1–13.5): the part of the variational stepper
(:class:`varint.schemes.variational.VariationalStepper`) that changes the lattice between steps — parcels injected at the inlet and removed at the outlet, the step rebuilt for the new
label set, the boundary fluxes booked into the balances, and the monitors and fields of an open tube, straight
(``_open_*``) or on a [rod] (``_oc_*``).  A mixin: it reads and writes the stepper's state, step and model; the
terms of the discrete Lagrangian stay in varint/terms/open_ends.py and varint/terms/step.py.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..errors import SolverError
from ..lattice.lie import cay_inv
from ..terms.rod import CHI, unpack_level
from ..terms.rod_constraint import constraint_jacobian, element_strain_residual
from ..terms.tube_potential import Config as T_Config
from .midpoint import make_scheme

__all__ = ["OpenEndsStepping"]


class OpenEndsStepping:
    """Lattice updates, balances, monitors and fields of open ends, mixed into the variational stepper."""

    def _rebuild(self):
        """The step, scales and Newton's reused factor after the open lattice changed (a label injected or removed)."""
        m = self.model
        m._layout()
        self.action = make_scheme(m, self.h, self.action.name, self._forces())
        self.scale, self.offset = self._scales()
        self._factor = None
        self._built_version = m.tube.lattice_version

    def _open_config(self, q, lam):
        """The open tube's configuration at a level: the free labels ``q``, the piston at its level position."""
        t = self.model.tube
        cfg = t.config(np.concatenate([q, lam]))
        if t.n_fixed:
            cfg.s[0] = t.piston
        return cfg

    def _open_energy(self, st):
        """(E, kinetic, potential terms, axial momentum, mass) of the open tube at the level of ``st``.

        E = sum_free p^2 / (2 mbar) + U(level): the level energy of the free labels and every parcel of L_d (the
        piston's kinetic energy is the inlet's, not the fluid's).  An incompressible liquid's potential is zero
        (its constraint holds at the half levels)."""
        m = self.model
        t = m.tube
        q, p, lam = st.q[m.tube_q], st.p[m.tube_p], st.lam[m.tube_lam]
        cfg = self._open_config(q, lam)
        if t.level_constraint:
            # a liquid held at the levels: the energy of the step that ended at the level (its velocities, the wall's
            # potential at its midpoint; record 0: the initial data's).  The level momentum p_n = D2 L_d' of this form
            # holds the wall's midpoint half-impulse -(h/2) grad U_wall, which the liquid's level impulse balances only
            # at the next level: read as a velocity it would be a kinetic energy that is not there (p_ext alone: 2 J
            # on a rubber tube at rest, docs/theory.md §13.8)
            v = st.v[m.tube_p]
            K = 0.5 * float(np.sum(t.mass * v * v))
            mid = self._open_config(q - 0.5 * self.h * v, lam)
            cfg_pot = T_Config(cfg.s, mid.R, cfg.mu)
            pot = t.energies(cfg_pot)
        else:
            K = 0.5 * float(np.sum(p * p / t.mass))
            pot = t.energies(cfg)
        P = float(np.sum(p[t.layout["s"]]))  # the labels' (a wall's radial momenta are not axial)
        return K + sum(pot.values()), K, pot, P, t.fluid_mass(cfg), cfg

    def _open_start(self):
        """t = 0: the balances' reference values, then the ends' rule applied to the initial lattice."""
        t = self.model.tube
        if self.model.coupled:
            self._oc_start()
            return
        E, _, _, P, mass, _ = self._open_energy(self._state)
        t.balance[:] = [E, P, mass, 0.0, 0.0, 0.0]
        self._open_update(self._state)
        self._state.data = self.model.state_data()

    def _open_fluxes(self, q0, p0, z):
        """Book one step's boundary fluxes (docs/theory.md §13.4, §13.8) and move the piston.

        A gas (the midpoint potential): energy, the piston's work dS_p dU/ds_p(c_mid) and the end forces' work
        (f^- + f^+) ds / h; axial momentum, the piston's reaction h dU/ds_p, the wall's axial force -h sum_k dU/ds_k (zero
        in a uniform duct) and the end forces' impulses f^- + f^+.  Exact identities of the step but for the midpoint
        rule's own energy error U(q1) - U(q0) - dq . grad U(c_mid), which vanishes when the parcels' volumes do not
        change.  A liquid held at the levels: the pressures and the end forces act at level n, h G(q_n)^T mu_n + f_n;
        the momentum changes by their sum over the free labels, the energy by their work with the labels' mean
        velocity across the level, (v_{n-1/2} + v_{n+1/2})/2 (the piston's: its central difference), up to
        mu . G(q_n) (q_{n+1} - q_{n-1}) / 2 = O(h^3): the pressures' work on the moving constraint surface."""
        m, h = self.model, self.h
        t = m.tube
        pt = self.action.point(q0, z)
        nf = t.n_fixed
        after = t.piston_after(h) if nf else None
        forces = t.forces[0].last
        dE = 0.0
        if t.level_constraint:
            term = next(x for x in self.action.terms if x.name == "level_constraint")
            g = t.level_weight * term.gradient_at_level(pt.q0, pt.lam, 0, h)[: t.M + 1]
            dP = -h * float(np.sum(g))
            if nf:  # the piston's work with the gauge pressure (below)
                g0 = t.level_weight * term.gradient_at_level(pt.q0, pt.lam - t.p_ext, 0, h)[0]
                dE += h * g0 * 0.5 * ((after - t.piston) / h + t.piston_velocity)
                dP += h * g[0]
            # a uniform pressure does no work on a liquid: the ends' flow work is booked with gauge pressures p - p_ext
            # (the datum's forces cancel the pressures' own on the end labels exactly; booked whole, the datum's work
            # would leave p_ext h (Q_out - Q_in), the level's O(h^2) volume mismatch, in the balance)
            for (i, fm, fp), (_, fm0, fp0) in zip(forces, t.forces[0].datum_forces(pt, t.p_ext)):
                u_mean = 0.5 * (p0[i] / t.mass[i] + (pt.q1[i] - pt.q0[i]) / h)
                dE += (fm + fp - fm0 - fp0) * u_mean
                dP += fm + fp
        else:
            cfg = t.config(np.concatenate([0.5 * (pt.q0 + pt.q1), pt.lam]))
            g = t.gradient(cfg)[: t.M + 1]
            for f in getattr(self, "extra_forces", ()):  # the energy-momentum step's mean-value pressures (§12d)
                if hasattr(f, "label_correction"):
                    g = g + f.label_correction(pt)
            dP = -h * float(np.sum(g))
            if nf:
                dE += (after - t.piston) * g[0]
                dP += h * g[0]
            for i, fm, fp in forces:
                dE += (fm + fp) * (pt.q1[i] - pt.q0[i]) / h
                dP += fm + fp
        t.balance[3] += dE
        t.balance[4] += dP
        if nf:
            t.piston_velocity = (after - t.piston) / h
            t.piston = after

    def _open_update(self, st):
        """Inject and remove parcels at a level (docs/theory.md §13.2-13.3), booking what they carry.

        A rigid tube's lattice holds the parcels whose centres are in the tube: when the first label passes half an
        inflow parcel beyond s = 0 a new label is prepended a parcel's volume upstream (a new parcel at the inlet's
        state); when the last parcel's centre passes s = L, that parcel and the last label are dropped; backflow by
        the mirror rules.  A dynamic wall's tube is kept full instead (thresholds at the ends themselves, the inlet's
        one step ahead).  Labels keep their level velocities, their masses become those of the new lattice (half a
        parcel at each end); what enters or leaves is booked into the balances' fluxes."""
        m = self.model
        t = m.tube
        ns = t.layout["s"].stop  # the free labels; a dynamic wall's radii follow them in q, p, v and do not change
        q, p, v, lam = st.q[:ns].copy(), st.p[:ns].copy(), st.v[:ns].copy(), st.lam.copy()
        qR, pR, vR = st.q[ns:], st.p[ns:], st.v[ns:]
        R_level = t.c0[t.index["R"]:t.index["R"] + t.nR].copy()
        if t.has_wall:
            R_level[1:-1] += qR
        duct = t.duct_at(R_level)
        # the ends' thresholds: a rigid tube keeps the parcels whose centres are inside, a dynamic wall's tube full
        in_at = 0.0 if t.filled else 0.5 * t.ell_in
        back_at = 0.0 if t.filled else 0.5 * t.ell_in
        changed = False
        done = set()  # what this update did at each end: it never undoes it (no injection/removal ping-pong)
        for _ in range(4 * t.M_max + 8):
            labels = np.concatenate([[t.piston], q]) if t.n_fixed else q
            # a full tube injects before the first label would enter it in the next step (its velocity: the piston's, or
            # the first label's last one), so that no wall is ever left without fluid inside
            ahead = self.h * (t.U_in if t.n_fixed else max(float(v[0]), 0.0)) if t.filled else 0.0
            if labels[0] + ahead >= in_at and "out@0" not in done:  # inject
                done.add("in@0")
                V_in = t.V_in
                if t.n_fixed and t.eos is not None:
                    # a velocity inlet prescribes U_in and the entering entropy; the new parcel enters at the pressure
                    # of the parcel it joins (the outgoing characteristic's): its volume follows, its mass is m_in
                    V0 = float(duct.volumes(labels[:2])[0])
                    p_adj = t.eos.pressure(t.m[0] / V0, t.S[0])
                    V_in = t.m_in / float(t.eos.density(p_adj, t.S_in))
                s_new = duct.below(labels[0], V_in)
                V_new = float(duct.volumes(np.array([s_new, labels[0]]))[0])
                psi = 0.0 if t.incompressible else float(t.eos.psi(np.array([V_new]), np.array([t.m_in]), np.array([t.S_in]))[0])
                if t.n_fixed:  # the piston is released with its level momentum mbar u_p (its last step's velocity)
                    mb = 0.5 * (t.m_in + t.m[0])
                    up = t.piston_velocity
                    q, p, v = np.r_[t.piston, q], np.r_[mb * up, p], np.r_[up, v]
                    dP, dE = mb * up, 0.5 * mb * up ** 2 + psi
                    t.piston = s_new
                    t.piston_velocity = t.U_in  # the new piston, in the inlet's section
                else:  # pressure inlet: half the new parcel joins the first label, half is the new first label
                    # the new label carries the first label's volume flux (in a varying duct a faster or slower speed: a
                    # liquid's volumes hold, and the level's constraint work stays O(h^3), docs/theory.md §13.8)
                    v0 = p[0] / (0.5 * t.m[0])
                    v_new = v0 * float(duct.A(labels[0])) / float(duct.A(s_new))
                    p[0] = 0.5 * (t.m_in + t.m[0]) * v0
                    q, p, v = np.r_[s_new, q], np.r_[0.5 * t.m_in * v_new, p], np.r_[v[0] * v_new / v0 if v0 else v[0], v]
                    dP = 0.5 * t.m_in * (v0 + v_new)
                    dE = 0.25 * t.m_in * (v0 ** 2 + v_new ** 2) + psi
                if t.incompressible:
                    # the new parcel's pressure (the predictor, and the field until its first step): extrapolated
                    lam = np.r_[2.0 * lam[0] - lam[1] if len(lam) > 1 else lam[0], lam]
                t.m, t.S = np.r_[t.m_in, t.m], np.r_[t.S_in, t.S]
                t.balance[3:] += [dE, dP, t.m_in]
                changed = True
                continue
            first_out = labels[1] < 0.0 if t.filled else 0.5 * (labels[0] + labels[1]) < 0.0
            if not t.n_fixed and len(t.m) > 2 and first_out and "in@0" not in done:
                done.add("out@0")
                # backflow at a pressure inlet: the first parcel's centre has left the tube upstream; it leaves
                ml, mp = 0.5 * t.m[0], 0.5 * (t.m[0] + t.m[1])
                vl, vp = p[0] / ml, p[1] / mp
                V_first = float(duct.volumes(labels[:2])[0])
                psi = 0.0 if t.incompressible else float(t.eos.psi(np.array([V_first]), t.m[:1], t.S[:1])[0])
                dm = mp - 0.5 * t.m[1]
                dP, dE = p[0] + dm * vp, 0.5 * ml * vl ** 2 + 0.5 * dm * vp ** 2 + psi
                p[1] = 0.5 * t.m[1] * vp
                q, p, v = q[1:], p[1:], v[1:]
                if t.incompressible:
                    lam = lam[1:]
                t.balance[3:] -= [dE, dP, t.m[0]]
                t.m, t.S = t.m[1:].copy(), t.S[1:].copy()
                changed = True
                continue
            if labels[-1] < t.L - back_at and "out@L" not in done:
                done.add("in@L")
                # backflow at the outlet: fluid is drawn in from outside at the outlet pressure (with the entropy of the
                # parcel it joins), half to the last label, half to a new last label, both at the last label's velocity
                S_new = t.S[-1]
                rho_new = t.rho0 if t.incompressible else float(t.eos.density(t.p_out, S_new))
                m_new = rho_new * duct.A_out * t.ell_in
                V_new = m_new / rho_new
                s_new = duct.above(labels[-1], V_new)
                psi = 0.0 if t.incompressible else float(t.eos.psi(np.array([V_new]), np.array([m_new]), np.array([S_new]))[0])
                vl = p[-1] / (0.5 * t.m[-1])
                v_new = vl * float(duct.A(labels[-1])) / float(duct.A(s_new))  # the same volume flux (as at the inlet)
                p[-1] = 0.5 * (t.m[-1] + m_new) * vl
                q, p, v = np.r_[q, s_new], np.r_[p, 0.5 * m_new * v_new], np.r_[v, v[-1] * v_new / vl if vl else v[-1]]
                if t.incompressible:
                    lam = np.r_[lam, 2.0 * lam[-1] - lam[-2] if len(lam) > 1 else lam[-1]]
                t.m, t.S = np.r_[t.m, m_new], np.r_[t.S, S_new]
                t.balance[3:] += [0.25 * m_new * (vl ** 2 + v_new ** 2) + psi, 0.5 * m_new * (vl + v_new), m_new]
                changed = True
                continue
            last_out = labels[-2] >= t.L if t.filled else 0.5 * (labels[-2] + labels[-1]) >= t.L
            if len(t.m) > 2 and last_out and "in@L" not in done:  # remove the last parcel
                done.add("out@L")
                ml, mp = 0.5 * t.m[-1], 0.5 * (t.m[-2] + t.m[-1])
                vl, vp = p[-1] / ml, p[-2] / mp
                V_last = float(duct.volumes(labels[-2:])[0])
                psi = 0.0 if t.incompressible else float(t.eos.psi(np.array([V_last]), t.m[-1:], t.S[-1:])[0])
                dm = mp - 0.5 * t.m[-2]
                dP = p[-1] + dm * vp
                dE = 0.5 * ml * vl ** 2 + 0.5 * dm * vp ** 2 + psi
                p[-2] = 0.5 * t.m[-2] * vp
                q, p, v = q[:-1], p[:-1], v[:-1]
                if t.incompressible:
                    lam = lam[:-1]
                t.balance[3:] -= [dE, dP, t.m[-1]]
                t.m, t.S = t.m[:-1].copy(), t.S[:-1].copy()
                changed = True
                continue
            break
        else:
            raise SolverError(f"{self._where(st.n)}: the open tube's ends changed more than {4 * t.M_max + 8} parcels in one "
                              "step; reduce time.step", step=st.n, time=st.t)
        if changed:
            if len(t.m) > t.M_max:
                raise SolverError(f"{self._where(st.n)}: the open tube holds {len(t.m)} parcels, more than the run file's "
                                  f"{t.M_max} slots (the gas compressed more than twofold); use fewer fluid.parcels",
                                  step=st.n, time=st.t)
            st.q, st.p, st.v, st.lam, st.q_prev = np.r_[q, qR], np.r_[p, pR], np.r_[v, vR], lam, None
            t._open_build()
            self._rebuild()
        elif t.n_fixed:
            t.c0[0] = t.piston

    def _open_monitors(self):
        """Energy, axial momentum and mass with their balances against the boundary fluxes (docs/theory.md §13.4)."""
        m, st = self.model, self.state
        t = m.tube
        E, K, pot, P, mass, cfg = self._open_energy(st)
        E0, P0, mass0, fE, fP, fm = t.balance
        p = st.p[m.tube_p]
        ns = t.layout["s"].stop
        Kw = (0.5 * float(np.sum(t.mass[ns:] * st.v[m.tube_p][ns:] ** 2)) if t.level_constraint
              else 0.5 * float(np.sum(p[ns:] ** 2 / t.mass[ns:])))
        out = {"kinetic_energy": K, "energy_fluid_kinetic": K - Kw, "energy_wall_kinetic": Kw}
        for k, val in pot.items():
            out[f"energy_{k}"] = val
        out["energy"] = E
        out["mass"] = mass
        out["linear_momentum"] = np.array([P, 0.0, 0.0])
        out["angular_momentum"] = np.zeros(3)
        out["energy_flux"] = fE
        out["momentum_flux"] = np.array([fP, 0.0, 0.0])
        out["mass_flux"] = fm
        out["energy_balance"] = E - E0 - fE
        out["momentum_balance"] = np.array([P - P0 - fP, 0.0, 0.0])
        out["mass_balance"] = mass - mass0 - fm
        out["parcels"] = int(t.M)
        out["entropy"] = float(np.sum(t.m * t.S))
        if t.incompressible:
            out["constraint_residual"] = float(np.max(np.abs(t.volumes(cfg) / t.V0 - 1.0)))
        return out

    def _open_fields(self):
        """Fields on the run file's fixed slots: label k (parcel k) is the k-th from the upstream end, NaN beyond
        the active ones; ``fluid/active`` marks the labels present (docs/output.md)."""
        m, st = self.model, self.state
        t = m.tube
        q, p, lam = st.q[m.tube_q], st.p[m.tube_p], st.lam[m.tube_lam]
        cfg = self._open_config(q, lam)
        Mx = t.M_max
        rho = t.density(cfg)
        pressure = lam.copy() if t.incompressible else t.eos.pressure(rho, t.S)
        ns = t.layout["s"].stop
        u = p[:ns] / t.mass[:ns]
        if t.n_fixed:
            u = np.r_[t.piston_velocity, u]
        lab = lambda x: np.r_[x, np.full(Mx + 1 - len(x), np.nan)]  # noqa: E731
        par = lambda x: np.r_[x, np.full(Mx - len(x), np.nan)]  # noqa: E731
        out = {"fluid/s": lab(cfg.s.copy()), "fluid/density": par(rho), "fluid/pressure": par(pressure),
               "fluid/velocity": lab(u), "fluid/entropy": par(t.S.copy()), "fluid/active": t.active_mask()}
        if t.has_wall:
            out["wall/R"] = cfg.R.copy()
            out["wall/velocity"] = np.r_[0.0, st.v[m.tube_p][ns:], 0.0]  # the end nodes are held
        return out

    # -- open ends on the coupled tube (docs/theory.md §13.1-13.4, the tube on a [rod]) ---------------------------
    # TubePart.balance of the coupled open tube (15 entries): E0, P0 (3), mass0, the accumulated energy flux, momentum
    # flux (3), mass flux, the supports' impulse (3, part of the momentum flux), the kinetic part of
    # the piston's last discrete momentum D2 L_d (for the inlet's kinetic impulse at the next level and the released
    # piston's momentum; a new piston's: its kinetic momentum) and the inlet's potential work over the last step

    def _oc_level(self, st):
        """(configuration of the tube, frames, positions, origin) of the level ``st``."""
        m = self.model
        cfg = m.tube.config(np.concatenate([st.q[m.tube_q], st.lam[m.tube_lam]]))
        Lam, r, origin = unpack_level(st.q[m.rod_q], m.N)
        return cfg, Lam, r, origin

    def _oc_metric(self, s, r):
        """(fluid metric, Jx, rod diagonal, X, X') of labels ``s`` (every label, the piston first) on the extended
        centreline: Xdot = Jx vel with vel = [per node (rdot, omega) | sdot per label] (docs/theory.md §10.5;
        varint.terms.coupled.kinetic_metric_of)."""
        from ..terms.coupled import kinetic_metric_of

        m = self.model
        rod = m.rod
        nodes, Nw, _, X, dX, _ = m.centreline(s, r)
        Mf, Jx = kinetic_metric_of(nodes, Nw, dX, m.tube.label_mass_all, rod.N + 1)
        rod_diag = np.concatenate([np.repeat(rod.node_mass[:, None], 3, axis=1), rod.node_inertia], axis=1).ravel()
        return Mf, Jx, rod_diag, X, dX

    def _oc_velocities(self, st, cfg, Lam, r):
        """Level velocities from the stored momenta in the kinetic metric (held components at rest, the piston at
        U_in; the inextensible rod's in its tangent space, as the closed coupled tube's monitor):
        (vel, Jx, rod diagonal, X, X')."""

        m = self.model
        t, rod = m.tube, m.rod
        n1, M, nf = rod.N + 1, t.M, t.n_fixed
        Mf, Jx, rod_diag, X, dX = self._oc_metric(cfg.s, r)
        Mt = Mf + sp.diags(np.concatenate([rod_diag, np.zeros(M + 1)]))
        known = np.zeros(6 * n1 + M + 1)
        if nf:
            known[6 * n1] = t.U_in
        active = np.concatenate([np.nonzero(rod.mask.ravel())[0], 6 * n1 + np.arange(nf, M + 1)])
        pr = st.p[m.rod_p].reshape(2, n1, 3).transpose(1, 0, 2).reshape(-1)
        ps = np.zeros(M + 1)
        ps[nf:] = st.p[m.tube_p][t.layout["s"]]
        rhs = (np.concatenate([pr, ps]) - Mt @ known)[active]
        Maa = Mt[active][:, active].tocsc()
        if rod.constrained:

            G = constraint_jacobian(Lam, r, rod.ds, rod.ncomp, rod.mask)
            G = sp.hstack([G, sp.csr_matrix((G.shape[0], len(active) - G.shape[1]))]).tocsr()
            K = sp.bmat([[Maa, G.T], [G, None]]).tocsc()
            va = spla.spsolve(K, np.concatenate([rhs, np.zeros(G.shape[0])]))[: len(active)]
        else:
            va = spla.spsolve(Maa, rhs)
        vel = known
        vel[active] = va
        return vel, Jx, rod_diag, X, dX

    def _oc_energy(self, st):
        """Energy terms, stored linear momentum and mass of the open coupled tube at the level ``st``.

        The energy of the step that ended at the level (as the closed coupled tube's with multipliers, §10.9): the
        kinetic energy of its velocities, (X_k^{n+1} - X_k^n)/h for every label (the piston's included) and the nodes'
        (r^{n+1} - r^n)/h and xi/h, plus the potential at its midpoint data (strain midpoint, rbar, sbar); record 0:
        the initial data's (velocities from the momenta in the kinetic metric, the potential at the level)."""

        m = self.model
        t, rod = m.tube, m.rod
        n1, h = rod.N + 1, self.h
        cfg, Lam, r, origin = self._oc_level(st)
        mbar = t.label_mass_all
        sec = rod.section
        if st.q_prev is None:  # t = 0: the initial data's velocities, from the momenta in the kinetic metric
            vel, Jx, rod_diag, X, dX = self._oc_velocities(st, cfg, Lam, r)
            Xdot = (Jx @ vel).reshape(-1, 3)
            Kr = 0.5 * float(np.sum(rod_diag * vel[: 6 * n1] ** 2))
            Om, Ga = rod.strains(Lam, r)
            rb, ob, Xb = r, origin, X
        else:  # the step that ended here
            Lp, rp, op = unpack_level(st.q_prev[m.rod_q], m.N)
            rp = rp + (op - origin)  # positions relative to this level's origin
            ns = t.layout["s"].stop
            s_prev = np.r_[np.full(t.n_fixed, t.piston - h * t.U_in), st.q_prev[:ns]]
            _, _, _, X, dX, _ = m.centreline(cfg.s, r)
            Xdot = (X - m.centreline(s_prev, rp)[3]) / h
            vr = (r - rp) / h
            w = cay_inv(np.swapaxes(Lp, 1, 2) @ Lam) / h
            Kr = 0.5 * float(np.sum(rod.node_mass[:, None] * vr * vr) + np.sum(rod.node_inertia * w * w))
            Om0, Ga0 = rod.strains(Lp, rp)
            Om1, Ga1 = rod.strains(Lam, r)
            Om, Ga = 0.5 * (Om0 + Om1), 0.5 * (Ga0 + Ga1)
            rb, ob = 0.5 * (r + rp), origin
            Xb = m.centreline(0.5 * (cfg.s + s_prev), rb)[3]
        Kf = 0.5 * float(np.sum(mbar * np.sum(Xdot * Xdot, axis=1)))
        dG = Ga - CHI
        bend = float(np.sum(rod.ds * 0.5 * np.sum(sec.J * Om * Om, axis=-1)))
        stretch = float(np.sum(rod.ds * 0.5 * np.sum(rod.K_energy * dG * dG, axis=-1)))
        grav = -float(np.sum(sec.rhoA * rod.w * ((rb + ob) @ rod.g))) - float(np.sum(mbar * ((Xb + ob) @ rod.g)))
        load = -float(np.dot(rod.force, rb[-1] + ob))
        terms = {"fluid_kinetic": Kf, "rod_kinetic": Kr, "bending_torsion": bend, "stretch_shear": stretch,
                 "gravity": grav, "load": load}
        P = st.p[m.rod_p][: 3 * n1].reshape(n1, 3).sum(0)
        mass = float(np.sum(rod.node_mass) + np.sum(t.m))
        return terms, P, mass, (cfg, Lam, r, origin, None, Xdot, dX)

    def _oc_start(self):
        """t = 0: the balances' reference values, the piston's momentum, then the ends' rule on the initial lattice."""
        t, st = self.model.tube, self._state
        terms, P, mass, (_, _, _, _, _, Xdot, dX) = self._oc_energy(st)
        b = np.zeros(15)
        b[0], b[1:4], b[4] = sum(terms.values()), P, mass
        b[13] = t.label_mass_all[0] * float(Xdot[0] @ dX[0])
        t.balance = b
        self._oc_update(st)
        st.data = self.model.state_data()

    def _oc_fluxes(self, q0, p0, z):
        """Book one step's boundary terms of the open coupled tube (docs/theory.md §13.4) and move the piston.

        The energy (the monitor) is the kinetic energy of the step that ended at the level (the labels' and nodes'
        velocities (X^{n+1} - X^n)/h, those of the updates) plus the potential at the level.
        Energy: the inlet's work, h U_in dU/dsbar_0 against the midpoint potential (the flow work of the inlet's pressure)
        plus U_in I_n, I_n = pi^-_n - pi^+_n the kinetic impulse of the piston at level n (pi^- = -D1 of the kinetic term
        in this step, pi^+ = its D2 in the last, on the piston's label).  Momentum: gravity (and a dead tip force) on rod and
        liquid, h (M_tot g + F), and the supports' impulse -(p_n + D1 L_d) on the held components (their rows are not
        solved): with these sum_j p_j changes exactly as the step's equations say, the kernels being translation
        invariant."""
        m, h = self.model, self.h
        t, rod = m.tube, m.rod
        b = t.balance
        pt = self.action.point(q0, z)
        fluid = next(x for x in self.action.terms if x.name == "fluid")
        pot, kin = fluid._parts(pt)
        if t.n_fixed:
            # the inlet's work: its force against the midpoint potential over the step, h U_in dU/dsbar_0 (the flow
            # work of the inlet pressure, the piston's weight), and U_in times the kinetic impulse at level n
            W_pot = -t.U_in * float(pot.D1.s[0] + pot.D2.s[0])
            # the energy is the step's (its midpoint's potential): the potential work between two midpoints is half
            # of each step's (the first step: half of its own)
            b[5] += t.U_in * (-float(kin.D1.s[0]) - b[13]) + 0.5 * (W_pot + b[14])
            b[13], b[14] = float(kin.D2.s[0]), W_pot
            if fluid.level_constraint:
                # a liquid held at the levels (theory §10.12): the pressure's impulse on the piston acts at level n,
                # h mu_n dV_0/ds_0 = -h dU_mu(q_n)/ds_0, whole between the two step energies
                g0 = fluid._level_volumes(pt, False)[0][1]
                b[5] += h * t.U_in * float(g0[fluid.off0["s"]])
        d = self.action._derivatives(pt, 0)
        for force in self.action.forces:
            force.add(pt, d, 0)
        n1 = rod.N + 1
        res = p0[m.rod_p][: 3 * n1].reshape(n1, 3) + d.rod[:, :3]
        R = -np.sum(res * ~rod.mask[:, :3], axis=0)
        M_tot = float(np.sum(rod.node_mass) + np.sum(t.label_mass_all))
        b[10:13] += R
        b[6:9] += h * (M_tot * rod.g + rod.force) + R
        if t.n_fixed:
            t.piston += h * t.U_in

    def _level_constraint(self):
        """True when the coupled liquid holds its volumes at the levels (varint.terms.step.CoupledFluid)."""
        return any(getattr(x, "level_constraint", False) for x in self.action.terms)

    def _oc_update(self, st):
        """Inject and remove parcels of the open coupled tube at a level (docs/theory.md §13.2-13.3, coupled).

        The tube holds the parcels whose centres are in it: when the piston passes half an inflow parcel beyond s = 0 it
        is released and a new piston is placed an inflow parcel upstream on the extended centreline (the new parcel's
        mass: the liquid's density times its stretched volume there); when the last parcel's centre passes s = L that
        parcel and the last label are dropped.  The stored momenta are kept and change only by what the changed label
        masses carry: dmbar_k Xdot_k on the nodes (weights N_j(s_k)) and dmbar_k Xdot_k . X'_k on the labels, with
        Xdot_k the label's velocity over the step that just ended, (X(s_k^{n+1}; r^{n+1}) - X(s_k^n; r^n)) / h (a new
        piston's: as if it had moved with the old one).  The released piston takes the kinetic part of its discrete
        momentum D2 L_d of that step, scaled to its new mass: its potential part, had it been free, would be the
        half-step impulse of the pressure difference across it and of its weight, which cancel in a steady flow (the
        hydrostatic gradient; all pressures equal without gravity).  What the change adds is booked as the fluxes."""
        m = self.model
        t, rod = m.tube, m.rod
        nf, ell, n1, h = t.n_fixed, t.ell_in, rod.N + 1, self.h
        ns = t.layout["s"].stop
        labels = np.r_[t.piston, st.q[:ns]]
        if labels[-1] < t.L - ell:
            raise SolverError(f"{self._where(st.n)}: the liquid flows back into the tube at its outlet, which the coupled "
                              "tube does not handle in this version", step=st.n, time=st.t)
        tie = 1e-9 * ell  # uniform flow meets both thresholds at the same level: round-off must not split them
        inject = labels[0] >= 0.5 * ell - tie
        remove = len(t.m) > 2 and 0.5 * (labels[-2] + labels[-1]) >= t.L - tie
        t.c0[0] = t.piston
        if not (inject or remove):
            return
        Lam, r, origin = unpack_level(st.q[m.rod_q], m.N)
        if st.q_prev is not None:
            _, r_prev, o_prev = unpack_level(st.q_prev[m.rod_q], m.N)
            labels_prev = np.r_[t.piston - h * t.U_in, st.q_prev[:ns]]
        else:  # t = 0: the initial data's velocities (the Legendre map of varint.model.model)
            leg = m.initial_legendre()
            r_prev, o_prev = r - h * rod.v0 * rod.mask[:, :3], origin
            labels_prev = labels - h * leg["sdot"]

        def velocity(s1, s0):
            return (m.centreline(s1, r)[3] + origin - m.centreline(s0, r_prev)[3] - o_prev) / h

        s_all, prev_all, vpred = labels.copy(), labels_prev.copy(), np.r_[t.U_in, st.v[:ns]]
        p_all = np.r_[np.nan, st.p[:ns]]  # the labels' momenta (the piston's is set below)
        m_all, fresh = t.m.copy(), np.zeros(len(t.m), bool)
        mb_old = np.r_[t.label_mass_all]
        lam_t, lam_r = st.lam[:t.nlam].copy(), st.lam[t.nlam:]
        removed_s, removed_prev, removed_mb = [], [], []
        injected = 0
        for _ in range(4 * t.M_max + 8):
            if s_all[0] >= 0.5 * ell - tie:
                s_all, prev_all, vpred = np.r_[s_all[0] - ell, s_all], np.r_[prev_all[0] - ell, prev_all], np.r_[t.U_in, vpred]
                p_all, mb_old = np.r_[np.nan, p_all], np.r_[0.0, mb_old]
                m_all, fresh = np.r_[t.m_in, m_all], np.r_[True, fresh]
                lam_t = np.r_[lam_t[0], lam_t]
                injected += 1
                continue
            if len(m_all) > 2 and 0.5 * (s_all[-2] + s_all[-1]) >= t.L - tie:
                removed_s.append(s_all[-1])
                removed_prev.append(prev_all[-1])
                removed_mb.append(mb_old[-1])
                s_all, prev_all, vpred, p_all, mb_old = s_all[:-1], prev_all[:-1], vpred[:-1], p_all[:-1], mb_old[:-1]
                m_all, fresh, lam_t = m_all[:-1], fresh[:-1], lam_t[:-1]
                continue
            break
        if len(m_all) > t.M_max:
            raise SolverError(f"{self._where(st.n)}: the open tube holds {len(m_all)} parcels, more than the run file's "
                              f"{t.M_max} slots", step=st.n, time=st.t)
        if np.any(fresh):
            m_all[fresh] = t.rho0 * m.open_volumes(s_all, Lam, r)[fresh]
        mass_old, mb0_piston = float(np.sum(t.m)), float(t.label_mass_all[0])
        t.m, t.S, t.piston = m_all, np.zeros(len(m_all)), float(s_all[0])
        t._open_build()
        mb_new = t.label_mass_all
        # what changed: every label of the new lattice (dmbar, its velocity), and the removed ones (-mbar)
        s_ch = np.r_[s_all, removed_s]
        dmb = np.r_[mb_new - mb_old, -np.asarray(removed_mb)]
        s_ch_prev = np.r_[prev_all, removed_prev]
        Xdot = velocity(s_ch, s_ch_prev)
        nodes, Nw, _, X, dX, _ = m.centreline(s_ch, r)
        # the monitor's potential is the step's midpoint's: the changed masses' weight at their midpoint positions
        Xb = m.centreline(0.5 * (s_ch + s_ch_prev), 0.5 * (r + r_prev + o_prev - origin))[3]
        dP_nodes = np.zeros((n1, 3))
        np.add.at(dP_nodes, nodes.ravel(), ((dmb[:, None] * Nw)[:, :, None] * Xdot[:, None, :]).reshape(-1, 3))
        b = t.balance
        b[5] += float(np.sum(dmb * (0.5 * np.sum(Xdot * Xdot, axis=1) - (Xb + origin) @ rod.g)))
        b[6:9] += dP_nodes.sum(0)
        b[9] += float(np.sum(t.m)) - mass_old
        k = len(s_all)
        lab_kin = mb_new * np.sum(Xdot[:k] * dX[:k], axis=1)
        p_new = p_all + dmb[:k] * np.sum(Xdot[:k] * dX[:k], axis=1)
        if injected:
            # the released piston (label `injected` now): its last D2 L_d, kinetic part at its new mass
            j = injected
            p_new[j] = b[13] * mb_new[j] / mb0_piston
            if self._level_constraint() and st.q_prev is not None:
                # a liquid held at the levels (theory §10.12): the pressure's impulse on the freed label comes whole in the
                # next step, so it keeps its D2 L_d's weight too, (h/2) mbar g . X'(sbar) of the step that ended, with
                # the piston's mass in that step (the joining mass was not in the tube: its momentum is kinetic)
                dXb = m.centreline(np.array([0.5 * (s_all[j] + prev_all[j])]), 0.5 * (r + r_prev + o_prev - origin))[4][0]
                p_new[j] += 0.5 * h * mb0_piston * float(rod.g @ dXb)
            p_new[:j] = lab_kin[:j]  # any further new labels: their kinetic momenta (the piston's, label 0, is data)
            b[13] = float(lab_kin[0])
        p_rod = st.p[ns:].copy()
        p_rod[: 3 * n1] += dP_nodes.ravel()
        st.q = np.r_[s_all[nf:], st.q[ns:]]
        st.p = np.r_[p_new[nf:], p_rod]
        st.v = np.r_[vpred[nf:], st.v[ns:]]
        st.lam = np.r_[lam_t, lam_r]
        st.q_prev = None if st.q_prev is None else np.r_[prev_all[nf:], st.q_prev[ns:]]  # on the new lattice
        self._rebuild()

    def _oc_monitors(self):
        """Energy, momentum and mass of the open coupled tube with their balances (docs/theory.md §13.4)."""
        m, st = self.model, self.state
        t, rod = m.tube, m.rod
        terms, P, mass, (cfg, Lam, r, origin, vel, Xdot, dX) = self._oc_energy(st)
        b = t.balance
        E = sum(terms.values())
        out = {"kinetic_energy": terms["fluid_kinetic"] + terms["rod_kinetic"],
               "energy_fluid_kinetic": terms["fluid_kinetic"], "energy_rod_kinetic": terms["rod_kinetic"]}
        for k in ("bending_torsion", "stretch_shear", "gravity", "load"):
            out[f"energy_{k}"] = terms[k]
        out["energy"] = E
        out["mass"] = mass
        out["linear_momentum"] = P
        n1 = rod.N + 1
        p = st.p[m.rod_p][: 3 * n1].reshape(n1, 3)
        Pi = st.p[m.rod_p][3 * n1:].reshape(n1, 3)
        out["angular_momentum"] = np.cross(origin, P) + np.cross(r, p).sum(0) + np.einsum("nij,nj->i", Lam, Pi)
        out["energy_flux"] = b[5]
        out["momentum_flux"] = b[6:9].copy()
        out["mass_flux"] = b[9]
        out["support_impulse"] = b[10:13].copy()
        out["energy_balance"] = E - b[0] - b[5]
        out["momentum_balance"] = P - b[1:4] - b[6:9]
        out["mass_balance"] = mass - b[4] - b[9]
        out["parcels"] = int(t.M)
        V = m.open_volumes(cfg.s, Lam, r)
        out["constraint_residual"] = float(np.max(np.abs(V / t.V0 - 1.0)))
        out["frame_orthogonality"] = float(np.max(np.abs(np.swapaxes(Lam, 1, 2) @ Lam - np.eye(3))))
        if rod.constrained:

            out["rod_constraint_residual"] = element_strain_residual(rod, Lam, r)
        return out

    def _oc_fields(self):
        """The open coupled tube's fields on the run file's fixed slots (docs/output.md)."""
        m, st = self.model, self.state
        t = m.tube
        cfg, Lam, r, origin = self._oc_level(st)
        geo = m.centreline(cfg.s, r)
        Mx = t.M_max
        lab = lambda x: np.r_[x, np.full((Mx + 1 - len(x),) + np.shape(x)[1:], np.nan)]  # noqa: E731
        par = lambda x: np.r_[x, np.full(Mx - len(x), np.nan)]  # noqa: E731
        ns = t.layout["s"].stop
        u = np.r_[np.full(t.n_fixed, t.U_in), st.v[m.tube_p][:ns]] * np.linalg.norm(geo[4], axis=1)
        return {"fluid/s": lab(cfg.s.copy()), "fluid/position": lab(geo[3] + origin),
                "fluid/density": par(t.m / t.V0), "fluid/pressure": par(cfg.mu + t.p_ext),
                "fluid/velocity": lab(u), "fluid/entropy": par(np.zeros(t.M)), "fluid/active": t.active_mask(),
                "rod/r": r + origin, "rod/Lambda": Lam.copy()}
