"""Shock capturing in the coupled tube: a viscous pressure on the stretched parcel volumes of a moving,
bending tube, by the discrete Lagrange–d'Alembert principle, and the heating it causes (docs/theory.md §11a,
"In the coupled tube").

On the coupled lattice (docs/theory.md §10) a parcel's volume at level l is the stretched volume of §10.3 at
that level's own strains,

    V_k^l = V_k(s^l, R^l, gamma(|Gamma^l|)),

a function of the labels, the radii and (through the element stretches |Gamma_e^l| of the rod's positions and
frames) of the rod nodes e0-1 .. e1+2 around the parcel.  It is invariant under a rigid motion of that level
alone, so everything built from it below is frame indifferent.  The force (:class:`CoupledShockCapturing`):

1. **Viscous pressure** Q_k, the law of varint.terms.shock_capturing (von Neumann & Richtmyer 1950, Landshoff 1955)
   with the compression rate du_k = (V_k^{n+1} - V_k^n)/(A h), A = pi R0^2 the rigid tube's cross-section
   (a dynamic wall: the parcel's mean cross-section at level n, :meth:`CoupledShockCapturing.cross_sections`):
   the rate of change of the parcel's length along the centreline, frame indifferent (a rigidly moving or
   spinning tube has V^{n+1} = V^n parcel by parcel and is not viscous); rho_k, c_k at Vbar_k = (V^n + V^{n+1})/2.
2. **Lagrange–d'Alembert pair** f^- = (h/2) sum_k Q_k grad V_k^n,  f^+ = (h/2) sum_k Q_k grad V_k^{n+1}: each
   level's force is Q times the gradient of that level's volumes in all the unknowns the volume reads (labels and
   rod nodes, [dr spatial, sigma body]), i.e. the trapezoidal rule for the work of the pressure Q on the
   parcel's volume.  Because V_k^l is invariant under a rigid motion of level l, sum_j f_j (force part) = 0 and
   sum_j (r_j x f_j + Lambda_j tau_j) = 0 at each level: the discrete Noether momenta P, J of §10.6 are kept to
   round-off.  The work of the pair over a step is (1/2) Q (grad V^n + grad V^{n+1}) . dq = Q dV + O(dq^3).
3. **Mean-value correction** (``mean_value``, on): the pair carries X_k = Q_k + P~_k - p(Vhat_k) instead of Q_k,
   P~_k = -(E_k(V^{n+1}) - E_k(V^n))/(V^{n+1} - V^n) the mean-value (discrete-gradient) pressure of §11a and
   Vhat_k = (V_k^n + V_k^{n+1})/2: the conservative term's midpoint pressure p(Vbar) (Vbar at the midpoint data,
   §10.4) is moved towards P~, whose work is exactly the internal energy's change.  Where V is linear in the
   unknowns (a straight tube) Vbar = Vhat and the pressure work is then exact; elsewhere the remainder is the
   coupled scheme's own O(h^2).
4. **Heating** (``after_step``): each parcel's entropy rises so that its internal energy at V^{n+1} grows by
   W_k = -Q_k (V_k^{n+1} - V_k^n) >= 0 (no parcel's entropy decreases; W >= 0 by construction).

The coupled midpoint scheme is variational, not a discrete-gradient scheme (its kinetic metric depends on the
labels and the rod lives on SO(3)), so its total energy is kept to O(h^2) (bounded), not to the Newton tolerance;
the force is built so that the shock adds nothing worse than that (docs/theory.md §11a, "In the coupled tube").

Scope: an ideal gas on a [rod], in a rigid tube or with a dynamic [wall] (then the radii are among the unknowns
V_k^l reads, and the rate uses the parcel's mean cross-section at level n, V_k^n / (s_{k+1}^n - s_k^n)); closed or
periodic ends.  A quasistatic wall (radii at half levels: V^{n+1} - V^n would miss the wall's motion) and open
ends are refused in one line (varint.scene.schema, varint.run.simulation).  The Newton block is exact: d f^-/dz = (h/2) G0^T diag(dQ/dV^{n+1}) G1 with G_l = dV^l/dq in
the step's chart, X for Q with the mean-value correction (tests/test_coupled_shock_capturing.py).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.sparse as sp

from .forces import Declaration, Force
from .shock_capturing import heated_entropy, limited, mean_value_pressure, set_viscosity, tridiagonal, viscous_pressure

__all__ = ["CoupledShockCapturing"]


class CoupledShockCapturing(Force):
    """The ``[shock_capturing]`` force of a coupled tube (module docstring).  Built by the tube part with the
    section's keys, bound to the model (:meth:`bind`) once the model's blocks exist.  ``last_work``: the
    viscous work of the last accepted step (sum of W_k, J); ``total_work``: since the start."""

    declaration = Declaration("shock_capturing", {"parcel_entropy": None})

    def __init__(self, tube, keys):
        set_viscosity(self, tube, keys)
        #: a dynamic wall: the compression rate uses each parcel's mean cross-section at level n (below)
        self.wall = bool(tube.has_wall)
        #: correct the midpoint pressure towards the mean-value one on the level volumes (docs/theory.md §11a)
        self.mean_value = True
        self.last_work = 0.0
        self.total_work = 0.0
        self._cache = None

    def bind(self, model):
        """Take the fluid term's maps (kernel ordering -> step unknowns) and build the volume-only potential."""
        from .coupled import newton_offsets
        from .step import CoupledFluid

        self.model = model
        self.cf = cf = CoupledFluid(model)
        t = self.tube
        M = t.M
        # U_mu = -sum_k mu_k V_k (no p_ext, no gravity): d/dmu = -V, and its (mu, q) Hessian block is -dV/dq
        self.fp0 = dataclasses.replace(cf.fp, eos=None, S=None, V0=np.zeros(M), p_ext=0.0, g=np.zeros(3))
        off, _ = newton_offsets(cf.n_nodes, M + 1, t.nR, M)
        self.off, self.nq = off, off["mu"]

    # -- the two levels ---------------------------------------------------------------------

    def _level_data(self, pt):
        cf = self.cf
        s0, R0, s1, R1, _, Lam1 = cf.levels(pt)
        k = cf.n_nodes
        return (s0, pt.r_n[:k], pt.Lam_n[:k], R0), (s1, pt.r_1[:k], Lam1[:k], R1)

    def _static(self, level, mu, hessian):
        from .coupled import fluid_potential_static

        s, r, Lam, R = level
        return fluid_potential_static(self.fp0, s, r, Lam, R, mu=mu, hessian=hessian)

    def volumes(self, level):
        """The stretched parcel volumes of one level (docs/theory.md §10.3)."""
        return -self._static(level, np.zeros(self.tube.M), False)[1][self.nq:]

    def volume_gradients(self, level):
        """(V, dV/dq) of one level: dV/dq (M, nq) in the kernel ordering [rod 6/node | s | R]."""
        _, g, H = self._static(level, np.zeros(self.tube.M), True)
        return -g[self.nq:], (-H[self.nq:, :self.nq]).tocsr()

    def _level_n(self, lv0, with_G):
        """Level n's volumes (and gradients): constant over a step, cached on its data."""
        key = tuple(np.asarray(a).tobytes() for a in lv0)
        c = self._cache
        if c is None or c[0] != key or (with_G and c[2] is None):
            if with_G:
                V, G = self.volume_gradients(lv0)
            else:
                V, G = self.volumes(lv0), None
            self._cache = c = (key, V, G)
        return c[1], c[2]

    def _K(self):
        t = self.tube
        return np.exp(t.S / self.cv) * t.m ** self.gamma

    def cross_sections(self, s0, V0):
        """A per parcel in the rate du = dV/(A h): pi R0^2 in a rigid tube; with a dynamic wall the parcel's mean
        cross-section per unit reference length at level n, V_k^n / (s_{k+1}^n - s_k^n) (as the straight swelling
        tube's, varint.terms.shock_capturing); both read level n only, so frame indifference is kept."""
        return V0 / np.diff(s0) if self.wall else self.A

    def pressures(self, V0, V1, h, s0=None):
        """(Q, dQ/dV1) per parcel; with the limiter also sets the neighbours' derivatives (``self._off``).  ``s0``:
        the level-n labels (needed with a wall)."""
        t = self.tube
        A = self.cross_sections(s0, V0)
        Q, dQ = viscous_pressure(V0, V1, t.m, self._K(), self.gamma, A, h, self.cQ, self.cL)
        self._off = None
        if self.limiter:
            Q, dQ, lo, up = limited(Q, dQ, V0, V1, A, h, t.periodic)
            self._off = (lo, up)
        return Q, dQ

    def forcing(self, V0, V1, h, s0=None):
        """(X, dX/dV1) per parcel: the pressure the force applies to the level volumes, X = Q, plus with
        ``mean_value`` the correction P~ - p(Vhat) of the midpoint pressure towards the mean-value one (Vhat =
        (V^n + V^{n+1})/2; docs/theory.md §11a, "In the coupled tube")."""
        Q, dQ = self.pressures(V0, V1, h, s0)
        if not self.mean_value:
            return Q, dQ
        K, g = self._K(), self.gamma
        P, dP = mean_value_pressure(V0, V1, K, g)
        Vh = 0.5 * (V0 + V1)
        ph = K * Vh ** (-g)
        return Q + P - ph, dQ + dP + 0.5 * g * ph / Vh

    def _valid(self, lv0, lv1):
        return self.cf._valid(lv0[0]) and self.cf._valid(lv1[0])

    # -- Force interface ---------------------------------------------------------------------

    def add(self, pt, d, level):
        """f^- (level 0) = (h/2) G0^T X, f^+ (level 1) = (h/2) G1^T X into the rod's, labels' and radii's rows."""
        t, cf = self.tube, self.cf
        lv0, lv1 = self._level_data(pt)
        if not self._valid(lv0, lv1):
            d.rod += np.nan
            d.tube_q += np.nan
            return
        V0 = self._level_n(lv0, False)[0]
        V1 = self.volumes(lv1)
        X = self.forcing(V0, V1, pt.h, lv0[0])[0]
        g = self._static(lv0 if level == 0 else lv1, X, False)[1]  # -G_l^T X in the kernel ordering
        f = -0.5 * pt.h * g[:self.nq]
        o, k = self.off, cf.n_nodes
        d.rod[:k] += f[:6 * k].reshape(k, 6)
        gc = np.zeros(t.nconfig)
        i = t.index
        gc[:i["R"]] = f[o["s"]:o["R"]]
        gc[i["R"]:i["R"] + t.nR] = cf.R_weight * f[o["R"]:o["mu"]]
        gz = cf.BT @ gc
        d.tube_q += gz[:t.nq]

    def jacobian(self, pt):
        """d f^-/dz = (h/2) Rot G0^T diag(dX/dV1) G1 Chart: translational rows in the level-n body frames (as the
        residual), columns through the chart dr = Lambda^n db, sigma = dcay_{-xi} dxi (docs/theory.md §10.9)."""
        from .coupled import level_chart_maps

        t, cf = self.tube, self.cf
        lv0, lv1 = self._level_data(pt)
        nz = self.model.nz
        if not self._valid(lv0, lv1):
            return sp.diags(np.full(nz, np.nan)).tocsc()
        V0, G0 = self._level_n(lv0, True)
        V1, G1 = self.volume_gradients(lv1)
        _, dX = self.forcing(V0, V1, pt.h, lv0[0])
        D = sp.diags(dX) if self._off is None else tridiagonal(dX, *self._off, t.periodic)
        k, nq = cf.n_nodes, self.nq
        Lam_n, xi = pt.Lam_n[:k], pt.xi[:k]
        Rot, Chart = level_chart_maps(Lam_n, xi, nq - 6 * k)
        Jk = (Rot @ (0.5 * pt.h * (G0.T @ D @ G1)) @ Chart).tocoo()
        r, c, v = Jk.row, Jk.col, Jk.data
        zr, zc = cf.z_of[r], cf.z_of[c]
        keep = (zr >= 0) & (zc >= 0)
        return sp.csc_matrix((v[keep] * cf.w_of[r[keep]] * cf.w_of[c[keep]], (zr[keep], zc[keep])), shape=(nz, nz))

    def work(self, pt):
        """Viscous work W_k = -Q_k (V_k^{n+1} - V_k^n) >= 0 done on each parcel over the step."""
        lv0, lv1 = self._level_data(pt)
        V0, V1 = self.volumes(lv0), self.volumes(lv1)
        Q = self.pressures(V0, V1, pt.h, lv0[0])[0]
        return -Q * (V1 - V0)

    def after_step(self, pt):
        """Heat each parcel by its viscous work: E_k(V^{n+1}, S_k') = E_k(V^{n+1}, S_k) + W_k."""
        t = self.tube
        lv0, lv1 = self._level_data(pt)
        V0, V1 = self.volumes(lv0), self.volumes(lv1)
        Q = self.pressures(V0, V1, pt.h, lv0[0])[0]
        W = np.maximum(-Q * (V1 - V0), 0.0)  # Q > 0 only where V1 < V0 (the max guards round-off)
        t.S[:] = heated_entropy(t.S, V1, self._K(), W, self.gamma, self.cv)
        self.last_work = float(np.sum(W))
        self.total_work += self.last_work
        self._cache = None
