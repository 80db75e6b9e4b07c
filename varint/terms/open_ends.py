"""Open ends of the straight tube: the duct on the extended line, its potential terms and the end forces.

``fluid.ends = { s0 = "inflow", sL = "outflow" }`` on a tube without ``[rod]`` (docs/theory.md §13.1-13.5).
The labels live on the extended line: beyond s = 0 and s = L the duct continues with the end's
cross-section (A_in = A(0), A_out = A(L)) and no wall, so a parcel's volume is

    V_k = F(s_{k+1}) - F(s_k),   F(s) = int_0^s A,   F' = A (continuous),  F'' = A' (jumps at nodes),

exact for the linear radius of §3 inside the tube and A times the length outside it.  The terms here are
those of varint.terms.tube_potential (internal energy, incompressibility) on this F: the same Config interface (label
positions ``cfg.s``, multipliers ``cfg.mu``), with values, gradients and tridiagonal Hessians in
configuration index space.  Rigid wall only (uniform radius or ``tube.area_table``): the radii are data.

The end forces enter by Lagrange-d'Alembert (varint.terms.forces, :class:`EndPressures`): the outlet's pressure on the
last label and at a pressure inlet p_in on the first, each on the section where that label is (docs/theory.md §13.8;
the outlets of §13.9).  A liquid on the straight tube is held at the levels (:class:`OpenLevelConstraint`).  A dynamic
wall's parcels use the lattice kernels on an extended lattice (:class:`ExtendedLattice`); the coupled tube's centreline
is extended by :class:`CoupledExtension`.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp

from .forces import Declaration, Force
from .shock_capturing import mean_value_pressure
from ..lattice.parcels import volume_below

__all__ = ["Duct", "OpenInternalEnergy", "OpenIncompressibility", "EndPressures", "OpenMeanValuePressure",
           "OpenLevelConstraint",
           "section_at", "open_end_limits"]


class Duct:
    """The rigid duct on the extended line: F(s) = int_0^s A, A(s) and A'(s) from the nodal radii ``R``."""

    def __init__(self, R, ds):
        self.R = np.asarray(R, dtype=np.float64)
        self.ds = float(ds)
        self.N = len(self.R) - 1
        self.L = self.N * self.ds
        self.uniform = bool(np.all(self.R == self.R[0]))
        self.A_in = math.pi * self.R[0] ** 2
        self.A_out = math.pi * self.R[-1] ** 2
        self.volume = float(volume_below(self.L, self.R, self.ds))

    def _locate(self, s):
        e = np.clip(np.floor(s / self.ds), 0, self.N - 1).astype(np.int64)
        t = s / self.ds - e
        return e, t, self.R[e], self.R[e + 1]

    def F(self, s):
        s = np.asarray(s, dtype=np.float64)
        if self.uniform:
            return self.A_in * s
        inside = volume_below(s, self.R, self.ds)
        return np.where(s < 0.0, self.A_in * s, np.where(s > self.L, self.volume + self.A_out * (s - self.L), inside))

    def A(self, s):
        s = np.asarray(s, dtype=np.float64)
        if self.uniform:
            return np.full(s.shape, self.A_in)
        e, t, a, b = self._locate(s)
        r = a + (b - a) * t
        return np.where(s < 0.0, self.A_in, np.where(s > self.L, self.A_out, math.pi * r * r))

    def dA(self, s):
        s = np.asarray(s, dtype=np.float64)
        if self.uniform:
            return np.zeros(s.shape)
        e, t, a, b = self._locate(s)
        r = a + (b - a) * t
        return np.where((s < 0.0) | (s > self.L), 0.0, 2.0 * math.pi * r * (b - a) / self.ds)

    def volumes(self, s):
        s = np.asarray(s, dtype=np.float64)
        if self.uniform:
            return self.A_in * np.diff(s)
        F = self.F(s)
        return F[1:] - F[:-1]

    def above(self, s_left, V):
        """The label x > s_left with F(x) - F(s_left) = V (the downstream label of a new parcel of volume V)."""
        return self._solve(float(self.F(s_left)) + V, s_left + V / float(self.A(s_left)))

    def below(self, s_right, V):
        """The label x < s_right with F(s_right) - F(x) = V (the upstream label of a new parcel of volume V)."""
        if self.uniform:
            return s_right - V / self.A_in
        return self._solve(float(self.F(s_right)) - V, s_right - V / float(self.A(s_right)))

    def _solve(self, target, x):
        """x with F(x) = target, by Newton from x."""
        if self.uniform:
            return target / self.A_in
        for _ in range(50):  # Newton on the monotone, C^1 F (quadratic convergence inside an element)
            dx = (float(self.F(x)) - target) / float(self.A(x))
            x -= dx
            if abs(dx) <= 4 * np.finfo(float).eps * max(abs(x), self.L):
                break
        return x


class _OpenParcelTerm:
    touches = ("s",)
    breaks = frozenset()

    def __init__(self, duct):
        self.duct = duct

    def volumes(self, cfg, cache):
        if "V" not in cache:
            cache["V"] = self.duct.volumes(cfg.s)
        return cache["V"]

    def _label_coeffs(self, cfg, cache):
        if "A" not in cache:
            cache["A"] = self.duct.A(cfg.s)
            cache["dA"] = self.duct.dA(cfg.s)
        return cache["A"], cache["dA"]

    @staticmethod
    def _grad_from(c1, A):
        """d/ds of sum_k psi_k(V_k) with psi_k' = c1_k: dV_k/ds_k = -A(s_k), dV_k/ds_{k+1} = A(s_{k+1})."""
        g = np.zeros(len(A))
        g[:-1] -= c1 * A[:-1]
        g[1:] += c1 * A[1:]
        return g

    @staticmethod
    def _hess_from(c1, c2, A, dA):
        """Tridiagonal Hessian of sum_k psi_k(V_k) (psi' = c1, psi'' = c2) in the labels, as COO triples."""
        n = len(A)
        diag = np.zeros(n)
        diag[:-1] += c2 * A[:-1] ** 2 - c1 * dA[:-1]
        diag[1:] += c2 * A[1:] ** 2 + c1 * dA[1:]
        off = -c2 * A[:-1] * A[1:]
        k = np.arange(n - 1)
        rows = np.concatenate([np.arange(n), k, k + 1])
        cols = np.concatenate([np.arange(n), k + 1, k])
        return rows, cols, np.concatenate([diag, off, off])


class OpenInternalEnergy(_OpenParcelTerm):
    """sum_k m_k e(m_k / V_k, S_k) on the extended duct."""

    name = "internal"

    def __init__(self, duct, eos, m, S):
        super().__init__(duct)
        self.eos, self.m, self.S = eos, m, S
        if not duct.uniform:
            self.breaks = frozenset({"axial_momentum"})

    def energy(self, cfg, cache):
        return float(np.sum(self.eos.psi(self.volumes(cfg, cache), self.m, self.S)))

    def gradient(self, cfg, cache, gs, gR, gmu):
        d1, _ = self.eos.dpsi(self.volumes(cfg, cache), self.m, self.S)
        A, _ = self._label_coeffs(cfg, cache)
        gs += self._grad_from(d1, A)

    def hessian(self, cfg, cache, index):
        d1, d2 = self.eos.dpsi(self.volumes(cfg, cache), self.m, self.S)
        A, dA = self._label_coeffs(cfg, cache)
        return self._hess_from(d1, d2, A, dA)


class OpenIncompressibility(_OpenParcelTerm):
    """-sum_k mu_k (V_k - V0_k) on the extended duct (mu: the pressure, as varint.terms.tube_potential.Incompressibility)."""

    name = "incompressibility"
    touches = ("s", "mu")

    def __init__(self, duct, V0):
        super().__init__(duct)
        self.V0 = V0
        if not duct.uniform:
            self.breaks = frozenset({"axial_momentum"})

    def energy(self, cfg, cache):
        return -float(np.dot(cfg.mu, self.volumes(cfg, cache) - self.V0))

    def gradient(self, cfg, cache, gs, gR, gmu):
        A, _ = self._label_coeffs(cfg, cache)
        gs += self._grad_from(-cfg.mu, A)
        gmu -= self.volumes(cfg, cache) - self.V0

    def hessian(self, cfg, cache, index):
        A, dA = self._label_coeffs(cfg, cache)
        r, c, v = self._hess_from(-cfg.mu, np.zeros_like(cfg.mu), A, dA)
        M = len(cfg.mu)
        k = np.arange(M)
        mu = index["mu"] + k
        # d^2/(ds_j dmu_k) = -dV_k/ds_j: +A(s_k) at j = k, -A(s_{k+1}) at j = k + 1
        jr = np.concatenate([k, k + 1])
        jv = np.concatenate([A[:-1], -A[1:]])
        jc = np.concatenate([mu, mu])
        return np.concatenate([r, jr, jc]), np.concatenate([c, jc, jr]), np.concatenate([v, jv, jv])


def section_at(x, R, ds):
    """The section at ``x`` of the linear radius on the nodal radii ``R`` (0..N), continued beyond each end with the
    end's section: (A, dA/dx, the two nodes of x's element, dA/dR at them).  Beyond an end, dA/dR is at the end node."""
    R = np.asarray(R, dtype=np.float64)
    N = len(R) - 1
    if x <= 0.0:
        return math.pi * R[0] ** 2, 0.0, (0, 0), (2.0 * math.pi * R[0], 0.0)
    if x >= N * ds:
        return math.pi * R[N] ** 2, 0.0, (N, N), (2.0 * math.pi * R[N], 0.0)
    e = min(int(x / ds), N - 1)
    t = x / ds - e
    r = R[e] + (R[e + 1] - R[e]) * t
    return (math.pi * r * r, 2.0 * math.pi * r * (R[e + 1] - R[e]) / ds, (e, e + 1),
            (2.0 * math.pi * r * (1.0 - t), 2.0 * math.pi * r * t))


class EndPressures(Force):
    """The forces at the open ends on the end labels (discrete Lagrange-d'Alembert, docs/theory.md §13.2-13.3, §13.8).

    Each end force is the end's pressure p_b times the section **where the end label is**, A(s_end): the force of
    the fluid outside on the face of the fluid inside.  (With the reference sections A(0), A(L) instead, a label
    inside a duct of varying section felt (p_b - p_parcel) A(0) + p_parcel (A(0) - A(s)): an error of the absolute
    pressure times the change of section, which made a liquid's flow depend on the pressure datum.)  With this
    section the end forces are minus the gradient of the reservoirs' work p_b F(s_end), F(s) = int_0^s A, the same
    quadrature as the parcels' pressures, so a uniform pressure added everywhere cancels exactly: Sum_k p dV_k/ds
    telescopes to p (A(s_M) - A(s_0)).

    *Where in the step.*  A gas (the midpoint potential): f^- = f^+ = +-(h/2) p_b A(sbar) at the step's midpoint
    sbar (and the radii's midpoint with a dynamic wall).  A liquid held at the levels (OpenLevelConstraint):
    f^- = +-h p_b A(s^n) at level n, f^+ = 0, like its pressures' level impulse h G(q_n)^T mu_n.
    The inlet (a pressure inlet) pushes the first label with p_in; the outlet pushes the last one back with
    p_b: ``pressure`` p_out; ``non-reflecting`` p_out + Z (v - u_ref), the characteristic impedance Z = rho c of the
    scene's fluid state (c the long-wave speed, with the wall's compliance) so that an outgoing wave
    p' = Z u' leaves without reflection; ``windkessel`` p_c + R1 Q, Q = A v the step's outflow and p_c the
    capacitor's pressure, C dp_c/dt = Q - (p_c - p_out)/R2 (trapezoidal over the step; p_c is state data).
    v is the end label's velocity over the step, (s^{n+1} - s^n)/h.  The Jacobian is exact; the step's values are
    kept in ``last`` (``after_step``) for the balances (their work is booked as flux through the ends, §13.4).
    """

    declaration = Declaration("open_ends", {"energy": None, "axial_momentum": None, "mass": None,
                                            "parcel_entropy": None})

    def __init__(self, tube):
        self.tube = tube
        #: the accepted step's [(index in the tube's q block, f^-, f^+)] (``after_step``), for the balances
        self.last = []

    # -- the boundary pressure of the outlet -------------------------------------------------------------
    def _outlet(self, v, A, h, midpoint):
        """(p_b, dp_b/dv at fixed A, dp_b/dA at fixed v) at the outlet for the end label's velocity v over the step and
        the section A there (the Windkessel's flow is Q = A v; ``midpoint``: its capacitor's mean over the step)."""
        t = self.tube
        kind = t.outflow
        if kind == "pressure":
            return t.p_out, 0.0, 0.0
        if kind == "non-reflecting":
            return t.p_out + t.Z_out * (v - t.u_ref), t.Z_out, 0.0
        # windkessel: p_b = p_c + R1 Q; the midpoint's capacitor pressure is the mean over the step
        Q = A * v
        R1, C, R2 = t.windkessel
        pc = t.p_c
        dpc = 0.0
        if midpoint:
            a, b = C / h + 0.5 / R2, C / h - 0.5 / R2
            pc1 = (pc * b + Q + t.p_out / R2) / a
            pc = 0.5 * (pc + pc1)
            dpc = 0.5 / a
        return pc + R1 * Q, (R1 + dpc) * A, (R1 + dpc) * v  # (p_b, dp_b/dv at fixed A, dp_b/dA at fixed v)

    def _R(self, q):
        t = self.tube
        if not t.has_wall:
            return t.R_reference
        R = t.R_reference.copy()
        ns = t.layout["s"].stop
        R[1:-1] += q[ns:ns + t.nR - 2]
        return R

    def _end_correction(self, which, x, xc, v, pt, i):
        """(dp, d dp/dv, d dp/dx, d dp/dxc): the steady Bernoulli pressure change between the end section and the end
        parcel where the lumped end label does not carry it, in a rigid duct of varying section (docs/theory.md §13.8).

        The lattice holds the parcels whose centres are in the tube, so the end label at ``x`` is within half a parcel
        of the end section, and its half parcel (from the parcel's centre ``xc``) is lumped at ``x``.  Label inside
        the tube: the fluid between it and the end section is missing, p(x) = p_end + 1/2 rho v^2 (r^2 - 1),
        r = A(x)/A_end (the volume flux A(x) v crosses the end section at v r).  Label beyond the end (the extended duct
        has the end's section, so the lumped label does not accelerate in steady flow) with its parcel's centre inside:
        the part of the half parcel inside the tube is missing its drop, p_end + 1/2 rho v^2 (1 - q^2),
        q = A_end / A(xc).  Zero in a uniform duct and with a dynamic wall (its end labels stay beyond the ends)."""
        t = self.tube
        d = t.duct
        if t.has_wall or d.uniform:
            return 0.0, 0.0, 0.0, 0.0
        outlet = which == "outlet"
        A_end = d.A_out if outlet else d.A_in
        inside = (x < t.L) if outlet else (x > 0.0)
        if t.incompressible:
            rho = t.rho0
        else:  # the end parcel's density at level n
            lab = np.r_[np.full(t.n_fixed, t.piston), pt.q0[: t.layout["s"].stop]]
            rho = float(t.m[-1] / d.volumes(lab[-2:])[0]) if outlet else float(t.m[0] / d.volumes(lab[:2])[0])
        if inside:
            r = float(d.A(x)) / A_end
            return (0.5 * rho * v * v * (r * r - 1.0), rho * v * (r * r - 1.0),
                    rho * v * v * r * float(d.dA(x)) / A_end, 0.0)
        if (xc >= t.L) if outlet else (xc <= 0.0):
            return 0.0, 0.0, 0.0, 0.0
        Ac = float(d.A(xc))
        q = A_end / Ac
        return 0.5 * rho * v * v * (1.0 - q * q), rho * v * (1.0 - q * q), 0.0, rho * v * v * q * q * float(d.dA(xc)) / Ac

    def step_forces(self, pt, correction=True):
        """[(i, f^-, f^+, {column: d f^-/d z_column})] of the step at ``pt``: i indexes the tube's q block (``correction``:
        with the end correction of :meth:`_end_correction`)."""
        t = self.tube
        h = pt.h
        ns = t.layout["s"].stop
        level = t.level_constraint
        out = []
        ends = [(ns - 1, -1.0, "outlet")]
        if t.inflow == "pressure":
            ends.insert(0, (0, 1.0, "inlet"))
        nothing = (0.0, 0.0, 0.0, 0.0)
        for i, sign, which in ends:
            v = (pt.q1[i] - pt.q0[i]) / h
            # the neighbour of the end label (its parcel's other label; the piston is data)
            j = i - 1 if which == "outlet" else i + 1
            if level:
                x = pt.q0[i]
                xn = pt.q0[j] if j >= 0 else t.piston
                A = section_at(x, self._R(pt.q0), t.ds)[0]
                if which == "inlet":
                    pb, dv = t.p_in, 0.0
                else:
                    pb, dv, _ = self._outlet(v, A, h, False)
                dp, dp_v, _, _ = self._end_correction(which, x, 0.5 * (x + xn), v, pt, i) if correction else nothing
                w = t.level_weight
                out.append((i, w * sign * h * (pb + dp) * A, 0.0, {i: w * sign * A * (dv + dp_v)}))
                continue
            sbar = 0.5 * (pt.q0[i] + pt.q1[i])
            if j >= 0:
                snb, jcol = 0.5 * (pt.q0[j] + pt.q1[j]), j
            else:  # the piston's midpoint (a velocity inlet has no inlet force: not reached)
                snb, jcol = t.c0[0], None
            if not t.has_wall and t.duct.uniform:  # one section everywhere, no end correction (the common case, fast)
                pb, dv = (t.p_in, 0.0) if which == "inlet" else self._outlet(v, t.duct.A_in, h, True)[:2]
                A = t.duct.A_in
                out.append((i, sign * 0.5 * h * pb * A, sign * 0.5 * h * pb * A, {i: sign * 0.5 * A * dv}))
                continue
            Rbar = 0.5 * (self._R(pt.q0) + self._R(pt.q1))
            A, dAds, nodes, dAdR = section_at(sbar, Rbar, t.ds)
            if which == "inlet":
                pb, dv, dA = t.p_in, 0.0, 0.0
            else:
                pb, dv, dA = self._outlet(v, A, h, True)
            dp, dp_v, dp_x, dp_xc = (self._end_correction(which, sbar, 0.5 * (sbar + snb), v, pt, i) if correction
                                     else nothing)
            f = sign * 0.5 * h * (pb + dp) * A
            cA = sign * 0.5 * h * (pb + dp + A * dA)  # d f / d A
            jac = {i: sign * 0.5 * A * (dv + dp_v) + 0.5 * cA * dAds + sign * 0.5 * h * A * (0.5 * dp_x + 0.25 * dp_xc)}
            if jcol is not None and dp_xc != 0.0:
                jac[jcol] = sign * 0.5 * h * A * 0.25 * dp_xc
            if t.has_wall:
                for j, w in zip(nodes, dAdR):
                    if 1 <= j <= t.nR - 2 and w != 0.0:
                        jac[ns + j - 1] = jac.get(ns + j - 1, 0.0) + 0.5 * cA * w
            out.append((i, f, f, jac))
        return out

    def datum_forces(self, pt, p):
        """[(i, f^-, f^+)] of a uniform pressure ``p`` at both ends (with the step's end sections)."""
        t = self.tube
        saved = (t.p_in, t.p_out, t.outflow)
        t.p_in, t.p_out, t.outflow = p, p, "pressure"
        try:
            return [(i, fm, fp) for i, fm, fp, _ in self.step_forces(pt, correction=False)]
        finally:
            t.p_in, t.p_out, t.outflow = saved

    def add(self, pt, d, level):
        for i, fm, fp, _ in self.step_forces(pt):
            d.tube_q[i] += fm if level == 0 else fp

    def jacobian(self, pt):
        t = self.tube
        rows, cols, vals = [], [], []
        for i, _, _, jac in self.step_forces(pt):
            for c, v in jac.items():
                if v != 0.0:
                    rows.append(i)
                    cols.append(c)
                    vals.append(v)
        if not rows:
            return None
        n = t.nz
        return sp.csc_matrix((vals, (rows, cols)), shape=(n, n))

    def after_step(self, pt):
        """Keep the accepted step's forces (the balances book them) and advance the Windkessel's capacitor."""
        t = self.tube
        self.last = [(i, fm, fp) for i, fm, fp, _ in self.step_forces(pt)]
        if t.outflow == "windkessel":
            i = t.layout["s"].stop - 1
            sbar = 0.5 * (pt.q0[i] + pt.q1[i])
            A = section_at(sbar, 0.5 * (self._R(pt.q0) + self._R(pt.q1)), t.ds)[0]
            Q = A * (pt.q1[i] - pt.q0[i]) / pt.h
            R1, C, R2 = t.windkessel
            a, b = C / pt.h + 0.5 / R2, C / pt.h - 0.5 / R2
            t.p_c = (t.p_c * b + Q + t.p_out / R2) / a


class OpenMeanValuePressure(Force):
    """The energy-momentum scheme's pressures in the open rigid uniform tube (docs/theory.md §12d, §13.4).

    The midpoint step's parcels push their labels with p(Vbar_k), the pressure at the step's mean volume; the
    energy-momentum step replaces it by the mean-value pressure Ptilde_k = -(psi_k(V^{n+1}) - psi_k(V^n)) / dV_k (an
    ideal gas or a barotropic liquid, varint.terms.shock_capturing.mean_value_pressure), so that the pressures' work
    over the step is the internal energy's change exactly.  In a rigid uniform duct V_k = A (s_{k+1} - s_k) is linear
    in the labels, so the correction is the force f^- = f^+ = (h/2) G^T X, X_k = Ptilde_k - p(Vbar_k), on the free
    labels, with each level's own labels: the piston (a velocity inlet) at its level positions (t.piston and
    t.piston_after(h)).  The lattice is read at each call, so the force follows the parcels injected and removed at
    the levels.  :meth:`label_correction` gives the same correction on every label, the piston's included, in the
    potential's gradient units, for the balances (the piston's work and reaction with Ptilde_0,
    varint.schemes.open_ends.OpenEndsStepping._open_fluxes): the energy balance then closes to the solver's tolerance.
    """

    declaration = Declaration("mean_value_pressure", {})

    def __init__(self, tube):
        self.tube = tube
        self.gamma = float(tube.eos.gamma)
        self.A = float(tube.duct.A_in)

    def _labels(self, q, level, h):
        t = self.tube
        free = q[: t.layout["s"].stop]
        if not t.n_fixed:
            return free
        return np.concatenate([[t.piston if level == 0 else t.piston_after(h)], free])

    def pressures(self, pt):
        """(X, dX/dV^{n+1}) per parcel: the mean-value pressure less the midpoint's."""
        t = self.tube
        V0 = self.A * np.diff(self._labels(pt.q0, 0, pt.h))
        V1 = self.A * np.diff(self._labels(pt.q1, 1, pt.h))
        _, K = t.eos.power_law(t.m, getattr(t, "S", None))  # (the constant part is its own mean value)
        P, dP = mean_value_pressure(V0, V1, K, self.gamma)
        Vb = 0.5 * (V0 + V1)
        pb = K * Vb ** (-self.gamma)
        return P - pb, dP + 0.5 * self.gamma * pb / Vb

    def label_correction(self, pt):
        """The correction to the potential's gradient dU/ds on every label (piston first): A (X_j - X_{j-1})."""
        X = self.pressures(pt)[0]
        return self.A * (np.concatenate([X, [0.0]]) - np.concatenate([[0.0], X]))

    def add(self, pt, d, level):
        ns = self.tube.layout["s"].stop
        d.tube_q[:ns] -= 0.5 * pt.h * self.label_correction(pt)[self.tube.n_fixed:]

    def jacobian(self, pt):
        """d f^-/dq^{n+1} = (h/2) A^2 D^T diag(dX/dV1) D on the free labels (D the parcels' label difference)."""
        t = self.tube
        dX = self.pressures(pt)[1]
        M, nf, ns = len(dX), t.n_fixed, t.layout["s"].stop
        k = np.arange(M)
        a, b = k - nf, k + 1 - nf  # the free-label columns of parcel k's two labels (-1: the piston)
        rows = np.concatenate([a, b, a, b])
        cols = np.concatenate([a, b, b, a])
        vals = 0.5 * pt.h * self.A * self.A * np.concatenate([dX, dX, -dX, -dX])
        keep = (rows >= 0) & (cols >= 0)
        return sp.csc_matrix((vals[keep], (rows[keep], cols[keep])), shape=(t.nz, t.nz))


class OpenLevelConstraint:
    """The open straight tube's liquid held at the levels (SHAKE; docs/theory.md §13.8, as §10.12 on the coupled tube).

    The step term h mu_n . g(q_n), g = V(s, R) - V0 the parcels' volumes at one level's own labels and radii, in place
    of the midpoint's -h mu . (V(sbar, Rbar) - V0): D1 += h G(q_n)^T mu_n (the pressures' impulse at level n), and the
    multiplier rows hold the new level, h g(q_{n+1}) = 0.  The midpoint constraint lets the levels alternate about the
    constraint surface (a neutral mode at phase pi, §10.12); in a duct of varying section its coefficients change as the
    labels move and the flow pumps it (measured: +-6e5 Pa growing without bound, from an inconsistency of 1e-7 m).
    With the constraint at the levels an alternation is off the surface, and the mode is gone.  The piston of a
    velocity inlet enters each level at its own position (t.piston, t.piston_after(h)).

    The first step takes half the level-0 impulse (``tube.level_weight`` = 1/2; RATTLE's first half kick): the
    momentum p_n of this form is M v_{n-1/2}, the velocity half a step before the level, so the initial data's M v(0)
    is the momentum after half of level 0's impulse (with the whole impulse the run lags by h/2: a uniformly
    accelerating column was h a / 2 fast)."""

    name = "level_constraint"
    order = 2

    def __init__(self, tube, offset, nz):
        self.tube, self.offset, self.nz = tube, offset, nz
        self.term = next(x for x in tube.terms if x.name == "incompressibility")
        self.Bq = tube.B[:, :tube.nq]
        self.Bl = tube.B[:, tube.nq:]
        self.BqT, self.BlT = self.Bq.T.tocsr(), self.Bl.T.tocsr()

    def config(self, q, lam, level, h):
        """The configuration at level n (``level`` 0) or n+1 (1) of a step of ``h``: the piston at its own position."""
        t = self.tube
        cfg = t.config(np.concatenate([q, lam]))
        if t.n_fixed:
            cfg.s[0] = t.piston if level == 0 else t.piston_after(h)
        return cfg

    def _grad(self, cfg):
        t = self.tube
        if t.label_problem(cfg) is not None:
            return np.full(t.nconfig, np.nan)
        gs, gR, gmu = np.zeros(t.index["R"]), np.zeros(t.nR), np.zeros(t.M)
        self.term.gradient(cfg, {}, gs, gR, gmu)
        return np.concatenate([gs, gR, gmu])

    def _hess(self, cfg):
        t = self.tube
        if t.label_problem(cfg) is not None:
            return sp.diags(np.full(t.nconfig, np.nan)).tocsr()
        r, c, v = self.term.hessian(cfg, {}, t.index)
        return sp.csr_matrix((v, (r, c)), shape=(t.nconfig, t.nconfig))

    def value(self, pt):
        return -pt.h * self.term.energy(self.config(pt.q0, pt.lam, 0, pt.h), {})

    def gradient_at_level(self, q, lam, level, h):
        """grad U_mu (configuration index space) at a level: the pressures' forces there are -this."""
        return self._grad(self.config(q, lam, level, h))

    def add(self, pt, d, level):
        if level != 0:
            return
        d.tube_q -= self.tube.level_weight * pt.h * (self.BqT @ self._grad(self.config(pt.q0, pt.lam, 0, pt.h)))
        d.tube_lam -= pt.h * (self.BlT @ self._grad(self.config(pt.q1, pt.lam, 1, pt.h)))

    def jacobian(self, pt):
        Hn = self._hess(self.config(pt.q0, pt.lam, 0, pt.h))
        H1 = self._hess(self.config(pt.q1, pt.lam, 1, pt.h))
        Jql = -self.tube.level_weight * pt.h * (self.BqT @ Hn @ self.Bl)
        Jlq = -pt.h * (self.BlT @ H1 @ self.Bq)
        nq, nl = self.Bq.shape[1], self.Bl.shape[1]
        J = sp.bmat([[sp.csr_matrix((nq, nq)), Jql], [Jlq, sp.csr_matrix((nl, nl))]]).tocsc()
        if self.offset == 0 and J.shape == (self.nz, self.nz):
            return J
        J = J.tocoo()
        return sp.csc_matrix((J.data, (J.row + self.offset, J.col + self.offset)), shape=(self.nz, self.nz))

    def constant_diagonal_jacobian(self):
        return False


class ExtendedLattice:
    """A dynamic wall's lattice extended by ``E`` elements beyond each end, with the padded nodes' radii those of the
    end nodes (R_{-j} = R_0, R_{N+j} = R_N): the linear interpolant is then the end's constant section outside the
    tube, and the lattice kernels of varint.lattice.parcels give the parcels' volumes on the extended line, with the
    outside parts' dependence on R_0 and R_N.  Labels are shifted by E ds into the kernels' coordinates; gradients
    and Hessians with respect to the padded radii are folded back onto the end nodes (the chain rule of the tie)."""

    def __init__(self, N, ds, E):
        self.N, self.ds, self.E = int(N), float(ds), int(E)
        self.shift = self.E * self.ds
        self.node_map = np.concatenate([np.zeros(self.E, np.int64), np.arange(self.N + 1), np.full(self.E, self.N)])

    def pad(self, R):
        return np.asarray(R, dtype=np.float64)[self.node_map]

    def fold(self, g_ext):
        g = np.zeros(self.N + 1)
        np.add.at(g, self.node_map, g_ext)
        return g

    def remap(self, idx, nlab, offset_R):
        """Configuration indices of the extended problem (labels 0..nlab-1, then extended nodes) -> the tube's
        (labels, then the real nodes from ``offset_R``)."""
        idx = np.asarray(idx, dtype=np.int64)
        node = idx >= nlab
        out = idx.copy()
        out[node] = offset_R + self.node_map[idx[node] - nlab]
        return out


class _WallParcelTerm:
    """Parcel terms on the extended lattice of a dynamic wall (varint.lattice.parcels kernels, labels and radii unknown)."""

    touches = ("s", "R")
    breaks = frozenset({"axial_momentum"})

    def __init__(self, ext):
        self.ext = ext

    def _args(self, cfg):
        return cfg.s + self.ext.shift, self.ext.pad(cfg.R)

    def volumes(self, cfg, cache):
        if "V" not in cache:
            from ..lattice.parcels import parcel_volumes

            s, R = self._args(cfg)
            cache["V"] = parcel_volumes(s, R, self.ext.ds, False, check=False)
        return cache["V"]

    def _derivs(self, cfg, c1, c2, hessian):
        from ..lattice.parcels import parcel_derivatives

        s, R = self._args(cfg)
        return parcel_derivatives(s, R, self.ext.ds, False, c1, c2, True, hessian, check=False)

    def _remap_coo(self, coo, nlab, index):
        r, c, v = coo
        return self.ext.remap(r, nlab, index["R"]), self.ext.remap(c, nlab, index["R"]), v


class WallInternalEnergy(_WallParcelTerm):
    """sum_k m_k e(m_k / V_k, S_k) on the extended lattice of a dynamic wall."""

    name = "internal"

    def __init__(self, ext, eos, m, S):
        super().__init__(ext)
        self.eos, self.m, self.S = eos, m, S

    def energy(self, cfg, cache):
        return float(np.sum(self.eos.psi(self.volumes(cfg, cache), self.m, self.S)))

    def gradient(self, cfg, cache, gs, gR, gmu):
        d1, d2 = self.eos.dpsi(self.volumes(cfg, cache), self.m, self.S)
        a, b, _, _ = self._derivs(cfg, d1, d2, False)
        gs += a
        gR += self.ext.fold(b)

    def hessian(self, cfg, cache, index):
        d1, d2 = self.eos.dpsi(self.volumes(cfg, cache), self.m, self.S)
        _, _, H, _ = self._derivs(cfg, d1, d2, True)
        return self._remap_coo(H, len(cfg.s), index)


class WallIncompressibility(_WallParcelTerm):
    """-sum_k mu_k (V_k - V0_k) on the extended lattice of a dynamic wall."""

    name = "incompressibility"
    touches = ("s", "R", "mu")

    def __init__(self, ext, V0):
        super().__init__(ext)
        self.V0 = V0

    def energy(self, cfg, cache):
        return -float(np.dot(cfg.mu, self.volumes(cfg, cache) - self.V0))

    def gradient(self, cfg, cache, gs, gR, gmu):
        a, b, _, _ = self._derivs(cfg, -cfg.mu, np.zeros_like(cfg.mu), False)
        gs += a
        gR += self.ext.fold(b)
        gmu -= self.volumes(cfg, cache) - self.V0

    def hessian(self, cfg, cache, index):
        _, _, H, (jr, jc, jv) = self._derivs(cfg, -cfg.mu, np.zeros_like(cfg.mu), True)
        r, c, v = self._remap_coo(H, len(cfg.s), index)
        jc = self.ext.remap(jc, len(cfg.s), index["R"])
        jr = np.asarray(jr, dtype=np.int64) + index["mu"]
        return np.concatenate([r, jr, jc]), np.concatenate([c, jc, jr]), np.concatenate([v, -jv, -jv])


class CoupledExtension:
    """The coupled tube's centreline extended beyond each open end (docs/theory.md §13.1, coupled).

    ``E`` ghost nodes beyond each end continue the rod straight along the end tangent of the closed tube,
    T_0 = (-3 r_0 + 4 r_1 - r_2) / (2 ds) (the one-sided second-order tangent of §10.2), ghost k at
    r_{-k} = r_0 - k ds T_0 = (1 + 3k/2) r_0 - 2k r_1 + (k/2) r_2, likewise beyond s = L; a ghost's frame is its
    end node's (Lambda_{-k} = Lambda_0), its radius the end node's.  The weights of each ghost sum to 1, so rigid
    motions of the rod move the extension rigidly.  The fluid kernels of varint.terms.coupled then read the labels on
    the extended lattice (labels shifted by E ds); their gradients and Newton blocks are folded back onto the real
    nodes by the chain rule of this linear tie (``fold_gradient``, ``fold_matrix``)."""

    def __init__(self, N, ds, E):
        self.N, self.ds, self.E = int(N), float(ds), int(E)
        self.shift = self.E * self.ds
        self.n_ext = self.N + 1 + 2 * self.E
        N, E = self.N, self.E
        rows, cols, vals = [E + np.arange(N + 1)], [np.arange(N + 1)], [np.ones(N + 1)]
        for k in range(1, E + 1):
            w = np.array([1.0 + 1.5 * k, -2.0 * k, 0.5 * k])
            rows += [np.full(3, E - k), np.full(3, E + N + k)]
            cols += [np.array([0, 1, 2]), np.array([N, N - 1, N - 2])]
            vals += [w, w]
        self.W = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                               shape=(self.n_ext, N + 1))
        self.WT = self.W.T.tocsr()
        #: the real node whose frame (and radius) each extended node has
        self.node_map = np.concatenate([np.zeros(E, np.int64), np.arange(N + 1), np.full(E, N)])
        self._coo = self.W.tocoo()

    def positions(self, r):
        return self.W @ np.asarray(r, dtype=np.float64)

    def node_weights(self):
        """(n_ext, 3) real nodes and weights of each extended node (zero-padded): r_a = sum_c ww[a, c] r[wn[a, c]]."""
        wn = np.zeros((self.n_ext, 3), np.int64)
        ww = np.zeros((self.n_ext, 3))
        W = self.W
        for a in range(self.n_ext):
            lo, hi = W.indptr[a], W.indptr[a + 1]
            wn[a, : hi - lo] = W.indices[lo:hi]
            ww[a, : hi - lo] = W.data[lo:hi]
        return wn, ww

    def frames(self, Lam):
        return np.ascontiguousarray(np.asarray(Lam)[self.node_map])

    def pad(self, R):
        return np.asarray(R, dtype=np.float64)[self.node_map]

    def fold_gradient(self, g_ext):
        """(n_ext, 6) [dr spatial | sigma body] -> (N+1, 6)."""
        g = np.zeros((self.N + 1, 6))
        g[:, :3] = self.WT @ g_ext[:, :3]
        np.add.at(g[:, 3:], self.node_map, g_ext[:, 3:])
        return g

    def fold_radii(self, g_ext):
        g = np.zeros(self.N + 1)
        np.add.at(g, self.node_map, g_ext)
        return g

    def fold_matrix(self, Lam_n, n_lab, n_mu):
        """G with u_ext = G u for the Newton chart (docs/theory.md §10.9): per extended node a, b_a = Lambda_f^nT
        sum_i W_ai Lambda_i^n b_i (f its frame node) and xi_a = xi_f; the label, radius and multiplier columns
        (``n_lab`` labels, a radius per node, the extended radii folded to their end nodes, ``n_mu`` multipliers)
        follow.  The Newton block of the real nodes is G^T J_ext G (its rows, Lambda_i^nT dL/dr_i, fold with the
        same blocks transposed)."""
        c = self._coo
        f = self.node_map[c.row]
        blocks = np.einsum("kji,kjl->kil", Lam_n[f], Lam_n[c.col]) * c.data[:, None, None]  # W_ai Lam_f^T Lam_i
        ii, jj = np.meshgrid(np.arange(3), np.arange(3), indexing="ij")
        rows = [(6 * c.row[:, None, None] + ii[None]).ravel()]
        cols = [(6 * c.col[:, None, None] + jj[None]).ravel()]
        vals = [blocks.ravel()]
        a = np.arange(self.n_ext)
        rows.append((6 * a[:, None] + 3 + np.arange(3)).ravel())
        cols.append((6 * self.node_map[:, None] + 3 + np.arange(3)).ravel())
        vals.append(np.ones(3 * self.n_ext))
        nR_ext, nR = self.n_ext, self.N + 1
        o_e, o_r = 6 * self.n_ext, 6 * (self.N + 1)
        rows.append(o_e + np.arange(n_lab))
        cols.append(o_r + np.arange(n_lab))
        vals.append(np.ones(n_lab))
        rows.append(o_e + n_lab + np.arange(nR_ext))
        cols.append(o_r + n_lab + self.node_map)
        vals.append(np.ones(nR_ext))
        rows.append(o_e + n_lab + nR_ext + np.arange(n_mu))
        cols.append(o_r + n_lab + nR + np.arange(n_mu))
        vals.append(np.ones(n_mu))
        shape = (o_e + n_lab + nR_ext + n_mu, o_r + n_lab + nR + n_mu)
        return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=shape)


def open_end_limits(model):
    """What open ends cannot run with in this version (docs/theory.md §13.7), in one line naming the key, or None."""
    t, sc = model.tube, model.scene
    if t is None or not t.open_ends:
        return None
    if model.rod is not None and not t.open:
        return ("fluid.ends: open ends on a [rod] (the coupled tube) run with an incompressible liquid in a rigid tube "
                "(no [wall]) and a velocity inlet in this version")
    if model.rod is not None and sc.fluid.initial:
        return "fluid.initial: a non-uniform start with open ends on a [rod] is not available in this version"
    if model.rod is not None and sc.fluid.ends.outflow != "pressure":
        return ("fluid.ends.outflow: open ends on a [rod] run with a free jet (outflow = 'pressure') in this version")
    if t.open and not t.coupled and t.outflow == "non-reflecting" and not math.isfinite(t.Z_out):
        return ("fluid.ends.outflow: a non-reflecting outlet needs waves to let out; an incompressible liquid in a rigid "
                "tube has none (add a [wall], or use 'pressure' or 'windkessel')")
    if model.rod is not None and t.p_out != t.p_ext:
        return ("fluid.ends.outflow_pressure: open ends on a [rod] run with a free jet (the outlet at "
                "environment.external_pressure) in this version")
    if t.has_wall and not t.wall_dynamic:
        return ("fluid.ends: open ends with a quasistatic [wall] are not available in this version; a rigid tube or a "
                "dynamic wall runs")
    if t.gx != 0.0 and model.rod is None:
        return ("environment.gravity: gravity along a straight tube with open ends is not available in this version "
                "(on a [rod] it is)")
    if sc.shock_capturing is not None:
        return "shock_capturing: not available with open ends in this version"
    return None
