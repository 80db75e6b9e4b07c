"""Open ends of the straight tube: the duct on the extended line, its potential terms and the end forces.

``fluid.ends = { s0 = "inflow", sL = "outflow" }`` on a tube without ``[rod]`` (docs/theory.md §13.1-13.5).
The labels live on the extended line: beyond s = 0 and s = L the duct continues with the end's
cross-section (A_in = A(0), A_out = A(L)) and no wall, so a parcel's volume is

    V_k = F(s_{k+1}) - F(s_k),   F(s) = int_0^s A,   F' = A (continuous),  F'' = A' (jumps at nodes),

exact for the linear radius of §3 inside the tube and A times the length outside it.  The terms here are
those of varint.terms.tube_potential (internal energy, incompressibility) on this F: the same Config interface (label
positions ``cfg.s``, multipliers ``cfg.mu``), with values, gradients and tridiagonal Hessians in
configuration index space.  Rigid wall only (uniform radius or ``tube.area_table``): the radii are data.

The end forces enter by Lagrange-d'Alembert (varint.terms.forces): the outlet pressure on the last label,
f^- = f^+ = -(h/2) p_out A_out, and at a pressure inlet p_in on the first label, f^± = +(h/2) p_in A_in.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp

from .forces import Declaration, Force
from ..lattice.parcels import volume_below

__all__ = ["Duct", "OpenInternalEnergy", "OpenIncompressibility", "EndPressures"]


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


class EndPressures(Force):
    """The pressures at the open ends on the end labels (discrete Lagrange-d'Alembert, docs/theory.md §13.2-13.3).

    Outlet: f^- = f^+ = -(h/2) p_out A_out on the last label (the jet's pressure on the fluid that has not left);
    pressure inlet: f^- = f^+ = +(h/2) p_in A_in on the first label.  Constant: no Jacobian block.  Their work
    over a step is (f^- + f^+) times the end label's displacement, their impulse f^- + f^+ (the balances).
    """

    declaration = Declaration("open_ends", {"energy": None, "axial_momentum": None, "mass": None,
                                            "parcel_entropy": None})

    def __init__(self, tube):
        self.tube = tube

    def end_forces(self, h):
        """(index of the first free label in the tube's s block or None, its f^-; index of the last, its f^-)."""
        t = self.tube
        sl = t.layout["s"]
        first = (sl.start, 0.5 * h * t.p_in * t.duct.A_in) if t.inflow == "pressure" else (None, 0.0)
        return first, (sl.stop - 1, -0.5 * h * t.p_out * t.duct.A_out)

    def add(self, pt, d, level):
        (i0, f0), (i1, f1) = self.end_forces(pt.h)
        if i0 is not None:
            d.tube_q[i0] += f0
        d.tube_q[i1] += f1


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
