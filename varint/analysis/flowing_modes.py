"""Linear modes of a tube conveying fluid: the coupled tube with open ends (``fluid.ends = { s0 = "inflow",
sL = "outflow" }``) linearised about its steady flow (docs/theory.md §13.6).

The scene is a [rod] + [fluid] tube with a rigid wall (no [wall]) and an incompressible liquid entering at s = 0
through a velocity inlet at U = ``fluid.ends.inflow_velocity`` (default ``fluid.velocity``) and leaving at s = L as
a free jet.  The liquid's plug speed along the tube is then fixed by the inlet, so the unknowns are the rod's only
(its (dr, sigma) on the support mask, as varint/model/statics.py).  The liquid's kinetic energy is the continuum
limit of the coupled model's label sum, evaluated with the Catmull-Rom weights N_i(s) of docs/theory.md §10.2
(X(s; r) = sum_i N_i(s) r_i):

    K_f = 1/2 int M |rdot(s) + U r'(s)|^2 ds
        = 1/2 rdot^T Mf rdot + U rdot^T G0 r + 1/2 U^2 r^T KU r,
    Mf = M int N N^T,  G0 = M int N N'^T,  KU = M int N' N'^T       (each (x) I_3 on the nodal positions),

with M = rho_f A the liquid's mass per length.  With the open system's momentum fluxes (McIver 1973; Benjamin
1961): -M U (rdot + U r')(L) . dr(L) of the jet leaving and +M U (rdot + U r')(0) . dr(0) of the fluid entering,
the linear equations are

    (M_rod + Mf) qddot + 2 U C1 qdot + (K_rod + U^2 S) q = 0,     C1 = M int N N'^T,  S = M int N N''^T,

the weak (Galerkin) form of  (m + M) wddot + 2 M U wdot' + M U^2 w'' + EI w'''' = 0  with the free end's
w'' = w''' = 0 (Païdoussis, *Fluid-Structure Interactions* vol. 1, eq. 3.70): the flux terms cancel the boundary
terms of the Lagrangian's integrations by parts (G0 - G0^T + M [N N^T]_0^L = 2 C1, -KU + M [N N'^T]_0^L = S).
Supported ends remove their rows (a pinned outlet has no transverse follower force).  At the straight state
S r = 0 (Catmull-Rom is exact on straight lines), so the straight flowing tube is an equilibrium with no base
tension: the axial follower force -M U^2 t(L) balances the axial pull +M U^2 t(L) of the centrifugal term.

The inextensible, unshearable rod (``rod.constraint = "inextensible_unshearable"``, docs/theory.md §9a; the garden
hose): the steady state solves the KKT system of the force balance with the constraint Gamma = chi and its element
forces lambda (as varint/model/statics.py ``static_equilibrium`` for the rod alone), and the linearisation adds the
geometric stiffness H_lambda of the base state's element forces and restricts the motion to the null space Z of the
constraint's Jacobian G:  (Z^T M Z) yddot + (Z^T C Z) ydot + (Z^T (K - H_lambda) Z) y = 0,  q = Z y
(docs/theory.md §13.6, "The inextensible, unshearable tube").

Base state: ``about="initial"``: the scene's (straight) initial state.  ``about="static"``: the steady state
under gravity, Newton on the rod's generalised force plus the liquid's weight M g int N_i and the steady flow's
force -U^2 S r (the centrifugal load of a bent steady state), with load continuation; the rod's internal force
there is the effective axial force T - pA of the flowing pipe (docs/theory.md §13.6), whose geometric stiffness
K_rod contains.  The modes are the eigenvalues s of the quadratic pencil, from its first-order generalised form
by dense shift-invert (the lowest eigenvalues accurate whatever the stiff axial and shear ones), reported as
``{"frequency": Im s >= 0, "growth_rate": Re s}`` (negative: decaying); a complex pair is reported once, each real
eigenvalue on its own.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from ..errors import SolverError

__all__ = ["flow_matrices", "flowing_linearization", "flowing_modes", "flowing_static", "pipe_parameters",
           "first_order_modes", "refuse_flowing"]

#: Gauss-Legendre points per element: N is cubic, so N N^T (degree 6) is integrated exactly by 4
_GAUSS = 4


def refuse_flowing(model, what="modes"):
    """One-line errors for what this linearisation (and :func:`flowing_static`) does not cover, before any matrix is
    built; ``what`` names the caller in the messages ("modes", "static equilibrium")."""
    sc = model.scene
    t, rod = model.tube, model.rod
    ends = sc.fluid.ends
    if not t.incompressible:
        raise SolverError(f"{what}: a flowing {sc.fluid.model} is not available (fluid.model): the {what} of a "
                          "tube conveying fluid are for an incompressible liquid")
    if t.has_wall:
        raise SolverError(f"{what}: a flowing tube with a [wall] is not available: the {what} of a tube conveying "
                          "fluid are for a rigid wall (remove [wall])")
    if sc.tube.area_table is not None:
        raise SolverError("tube.area_table: a flowing tube needs a uniform section (the flow speed would vary along it)")
    if ends.inflow != "velocity":
        raise SolverError(f"fluid.ends.inflow: the {what} of a flowing tube need a velocity inlet (\"velocity\"), "
                          "which fixes the liquid's speed")
    if ends.outflow_pressure != sc.environment.external_pressure:
        raise SolverError(f"fluid.ends.outflow_pressure: the {what} of a flowing tube are for a free jet at the external "
                          f"pressure ({sc.environment.external_pressure:g} Pa), got {ends.outflow_pressure:g} Pa")
    if rod.periodic:
        raise SolverError(f"{what}: a flowing tube with periodic rod ends (rod.ends) is not available")
    if np.any(rod.spin) or np.any(rod.velocity):
        raise SolverError(f"{what}: a flowing tube is linearised about its steady flow: rod.initial.velocity and "
                          "rod.initial.angular_velocity must be zero")
    if rod.free:
        raise SolverError(f"{what}: a flowing tube with both rod.ends free has no steady state; clamp or pin an end")


def pipe_parameters(model):
    """The pipe's classical data: ``U`` (m/s), ``M`` (liquid kg/m), ``m`` (rod kg/m), ``EI``, ``L``, ``g`` (the
    gravity component along the undeformed tube from s = 0 to s = L, m/s^2) and Païdoussis' dimensionless
    ``u`` = U L sqrt(M/EI), ``beta`` = M/(M+m), ``gamma`` = (M+m) g L^3/EI (> 0 hanging)."""
    sc, t, rod = model.scene, model.tube, model.rod
    U = float(sc.fluid.ends.inflow_velocity)
    M = float(np.sum(t.label_mass_all)) / t.L
    m, EI, L = rod.section.rhoA, rod.section.EI, rod.L
    axis = rod.r0[-1] - rod.r0[0]
    g_along = float(np.dot(rod.g, axis / np.linalg.norm(axis)))
    return {"U": U, "M": M, "m": m, "EI": EI, "L": L, "g": g_along, "u": U * L * np.sqrt(M / EI),
            "beta": M / (M + m), "gamma": (M + m) * g_along * L ** 3 / EI}


def flow_matrices(n_nodes, ds, M=1.0):
    """(Mf, C1, S, W): M int N_i N_j, M int N_i N_j', M int N_i N_j'' and M int N_i over [0, L] for the
    Catmull-Rom weights of varint/lattice/centreline.py (closed ends: quadratic-extrapolation ghosts), exactly
    (4 Gauss points per element); sparse (n_nodes, n_nodes) (a band of 3 each side: the 4-node stencil) and a
    vector (n_nodes,)."""
    from ..lattice.centreline import centreline_weights

    x, w = np.polynomial.legendre.leggauss(_GAUSS)
    n_el = n_nodes - 1
    s = ((np.arange(n_el)[:, None] + 0.5 * (x[None, :] + 1.0)) * ds).ravel()
    wq = np.tile(0.5 * ds * w, n_el)
    nodes, N, dN, d2N = centreline_weights(s, n_nodes, ds)
    # dense weight matrices (points x nodes): a node may appear twice in a row (folded ghosts), so add
    rows = np.repeat(np.arange(len(s)), 4)
    Nq, dNq, d2Nq = (sp.csr_matrix((a.ravel(), (rows, nodes.ravel())), shape=(len(s), n_nodes)) for a in (N, dN, d2N))
    NW = (sp.diags(M * wq) @ Nq).T.tocsr()
    return (NW @ Nq).tocsr(), (NW @ dNq).tocsr(), (NW @ d2Nq).tocsr(), np.asarray(NW @ np.ones(len(s))).ravel()


def _on_rod(A, rod):
    """A node matrix (n_nodes^2) (x) I_3 on the translations, restricted to the rod's support mask (sparse nz x nz)."""
    E = np.zeros((6, 6))
    E[:3, :3] = np.eye(3)
    big = sp.kron(sp.csr_matrix(A), sp.csr_matrix(E)).tocsr()
    idx = np.flatnonzero(rod.mask.ravel())
    return big[idx][:, idx].tocsr()


def _flow_force(rod, r, S, W, g, U, lf=1.0):
    """The liquid's generalised force on the rod's (dr, sigma) (N+1, 6): its weight lf M g int N_i and the steady
    flow's -lf U^2 (S r)_i."""
    f = np.zeros((rod.N + 1, 6))
    f[:, :3] = lf * (W[:, None] * g[None, :] - U * U * (S @ r))
    return f


def flowing_static(model, steps=4, tol=1e-10, max_iter=40, velocity=None):
    """The steady state of the flowing tube under gravity: Newton on rod force + liquid weight + steady flow force
    = 0 in the rod's chart (Lambda cay(sigma), r + dr), with load continuation in gravity and U^2 together
    (varint/model/statics.py ``load_continuation``); ``velocity`` overrides the inlet's U.

    The inextensible, unshearable rod: Newton on the KKT system [[dF/dz + H_lambda, -ds G^T], [G, 0]] of that force
    balance with the constraint Gamma = chi and its element forces lambda (docs/theory.md §13.6), as
    ``static_equilibrium`` does for the rod alone; ``info["element_forces"]`` (N, 3) holds lambda (body frame; the
    first ``rod.ncomp`` components are used).
    Returns ((Lambda, r), info) with info's ``load_steps`` and ``iterations``."""
    import warnings

    import scipy.sparse.linalg as spla

    from ..model.statics import force_jacobian, potential_gradient, retract, load_continuation
    from ..terms.rod_constraint import constraint_static

    refuse_flowing(model, "static equilibrium")
    rod = model.rod
    par = pipe_parameters(model)
    _, _, S, W = flow_matrices(rod.N + 1, rod.ds, par["M"])
    U = par["U"] if velocity is None else float(velocity)
    g, mask = np.asarray(rod.g, dtype=float), rod.mask
    Sz = _on_rod(S, rod)
    scale = np.where(np.flatnonzero(mask.ravel()) % 6 < 3, rod.ds, 1.0)
    nz, ncomp = rod.nz, rod.ncomp

    def newton_step(state, lf):
        Lam, r, lam = state
        f = (potential_gradient(rod, Lam, r, lf) + _flow_force(rod, r, S, W, g, U, lf))[mask]
        J = force_jacobian(rod, Lam, r, lf) - lf * U * U * Sz
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", spla.MatrixRankWarning)
            if rod.constrained:
                # the force balance with the constraint forces -ds G^T lam, and Gamma = chi
                c, G, Fc, Hc = constraint_static(rod, Lam, r, lam)
                K = sp.bmat([[J + Hc, -rod.ds * G.T], [G, None]]).tocsc()
                d = -spla.spsolve(K, np.concatenate([f + Fc, c]))
                dz = d[:nz]
                if np.all(np.isfinite(d)):
                    lam = lam.copy()
                    lam[:, :ncomp] += d[nz:].reshape(rod.N, ncomp)
            else:
                dz = -spla.spsolve(sp.csc_matrix(J), f)
        if not np.all(np.isfinite(dz)):
            return state, None
        Lam, r = retract(Lam, r, dz, mask)
        return (Lam, r, lam), bool(np.max(np.abs(dz) / scale) < tol)

    (Lam, r, lam), n_steps, iters = load_continuation(
        lambda: (rod.Lam0.copy(), rod.r0.copy(), np.zeros((rod.N, 3))), newton_step, steps, max_iter)
    info = {"load_steps": n_steps, "iterations": iters}
    if rod.constrained:
        info["element_forces"] = lam.copy()
    return (Lam, r), info


def flowing_linearization(model, about="initial", velocity=None):
    """Mass, damping (gyroscopic + the flux terms) and stiffness of the flowing tube in the rod's unknowns.

    ``velocity``: the flow speed U (m/s) in place of the scene's inlet velocity (0 allowed: the tube full of
    liquid at rest, whose lateral inertia is the same M per length).
    Returns a dict: ``M``, ``C``, ``K`` (C and K not symmetric), ``Lam``, ``r`` (the base state), ``parameters``
    (:func:`pipe_parameters`), ``unbalanced`` (the generalised force at the base state over the elastic force of a
    unit strain: ~0 at an equilibrium) and ``Z``: None, and M, C, K are sparse (nz x nz) on the rod's unknowns; or,
    for the inextensible, unshearable rod, the orthonormal basis (nz x nz - rank G) of the null space of the
    constraint's Jacobian G, and M, C, K are the dense restrictions Z^T M Z, Z^T C Z, Z^T (K - H_lambda) Z
    (H_lambda: the geometric stiffness of the base state's element forces ``element_forces``, zero about the
    initial state; docs/theory.md §13.6), whose eigenvectors y give the displacements Z y.
    """
    from ..model.statics import force_jacobian, potential_gradient, lumped_mass

    refuse_flowing(model)
    rod = model.rod
    par = pipe_parameters(model)
    if velocity is not None:
        par = dict(par, U=float(velocity), u=float(velocity) * par["L"] * np.sqrt(par["M"] / par["EI"]))
    lam = np.zeros((rod.N, 3))
    if about == "static":
        (Lam, r), info = flowing_static(model, velocity=par["U"])
        lam = info.get("element_forces", lam)
    else:
        Lam, r = rod.Lam0, rod.r0
    U = par["U"]
    Mf, C1, S, W = flow_matrices(rod.N + 1, rod.ds, par["M"])
    Kr = -force_jacobian(rod, Lam, r)
    force = potential_gradient(rod, Lam, r) + _flow_force(rod, r, S, W, np.asarray(rod.g, dtype=float), U)
    force = force[rod.mask]
    if rod.constrained:
        from ..terms.rod_constraint import constraint_static

        _, G, Fc, Hc = constraint_static(rod, Lam, r, lam)
        Kr = Kr - Hc
        force = force + Fc
    Kr = (0.5 * (Kr + Kr.T)).tocsr()
    Mz = sp.diags(lumped_mass(rod)[rod.mask]) + _on_rod(Mf, rod)
    Mz = (0.5 * (Mz + Mz.T)).tocsr()
    C = (2.0 * U * _on_rod(C1, rod)).tocsr()
    K = (Kr + U * U * _on_rod(S, rod)).tocsr()
    Z = None
    if rod.constrained:
        # the motions that keep Gamma = chi to first order: q = Z y, G Z = 0 (docs/theory.md §13.6)
        Z = sla.null_space(G.toarray())
        Mz, C, K = (Z.T @ (X @ Z) for X in (Mz, C, K))
        Mz = 0.5 * (Mz + Mz.T)
    unit = np.where(np.flatnonzero(rod.mask.ravel()) % 6 < 3, rod.ds, 1.0)
    size = float(np.max(np.abs(Kr.diagonal()) * unit))
    return {"M": Mz, "C": C, "K": K, "Z": Z, "Lam": Lam, "r": r, "parameters": par,
            "unbalanced": float(np.max(np.abs(force))) / size if size > 0 else 0.0}


#: above this many unknowns the first-order eigenproblem is solved by sparse shift-invert Arnoldi for the lowest
#: modes (dense: every mode, O((2n)^3)); measured for 8 modes, dense / sparse: 0.04 / 0.02 s at n = 60,
#: 0.21 / 0.035 s at n = 120, 1.1 / 0.03 s at n = 240, 7-15 s / 0.1 s at n = 600 (shared machine).  The dense
#: path is kept below 400 for its accuracy at a near-double eigenvalue: 1e-5 above a divergence the sparse
#: growth rate is 2.5e-4 off (0.04173 against 0.04172) and the merging pair can show a spurious frequency
DENSE_FLOWING_LIMIT = 400


def first_order_modes(K, C, M, count=20, vectors=False, shift=None, method="auto"):
    """Eigenvalues s of (s^2 M + s C + K) x = 0 (any K, C; M symmetric positive semi-definite) as modes.

    First-order form [[0, I], [-K, -C]] y = s [[I, 0], [0, M]] y, by shift-invert about ``shift`` (default:
    -1e-3 of the smallest sqrt(K_ii/M_ii)): the eigenvalues mu of (A - shift B)^-1 B give s = shift + 1/mu, so
    the lowest s carry the round-off of the lowest, not of the stiffest, modes; mu = 0 (an infinite s of a
    massless unknown) is dropped.  ``method``: "dense" (every eigenvalue, LAPACK), "sparse" (the 2 count + 8
    nearest the shift, ARPACK on the operator with a sparse LU) or "auto" (sparse above
    :data:`DENSE_FLOWING_LIMIT` unknowns).  Returns ``[{"frequency": Im s, "growth_rate": Re s}, ...]``:
    one entry per complex-conjugate pair (Im s > 0) and one per real eigenvalue; parts below 1e-6 |s| are
    round-off (0).  Sorted by frequency, then growth rate descending; ``count`` first.  With ``vectors`` the
    complex displacement parts too.
    """
    n = K.shape[0]
    if n == 0:
        return ([], np.zeros((0, 0))) if vectors else []
    Kd, Md = np.asarray(_diag(K)), np.asarray(_diag(M))
    if shift is None:
        d = np.abs(Kd) / np.maximum(Md, 1e-300)
        d = d[Md > 0]
        shift = -1e-3 * float(np.sqrt(np.min(d[d > 0]))) if np.any(d > 0) else -1.0
    if method == "sparse" or (method == "auto" and n > DENSE_FLOWING_LIMIT and 2 * count + 8 < 2 * n - 2):
        mu, Y = _sparse_mu(K, C, M, shift, min(2 * count + 8, 2 * n - 2))
    else:
        K, C, M = (x.toarray() if sp.issparse(x) else np.asarray(x) for x in (K, C, M))
        I = np.eye(n)
        A = np.block([[np.zeros((n, n)), I], [-K, -C]])
        B = np.block([[I, np.zeros((n, n))], [np.zeros((n, n)), M]])
        T = sla.lu_solve(sla.lu_factor(A - shift * B), B)
        mu, Y = sla.eig(T)
    big = float(np.max(np.abs(mu)))
    ok = np.abs(mu) > 1e-13 * big
    s = shift + 1.0 / mu[ok]
    Y = Y[:n, ok]
    # round-off: a near-double eigenvalue (two frequencies about to merge at a divergence or a flutter threshold)
    # is split by ~sqrt(eps) of its size, so parts below 1e-6 |s| are taken as 0
    tiny = 1e-6 * np.abs(s)
    re = np.where(np.abs(s.real) <= tiny, 0.0, s.real)
    im = np.where(np.abs(s.imag) <= tiny, 0.0, s.imag)
    keep = np.flatnonzero(im >= 0.0)
    res = [{"frequency": float(im[i]), "growth_rate": float(re[i])} for i in keep]
    order = sorted(range(len(res)), key=lambda k: (res[k]["frequency"], -res[k]["growth_rate"]))[:count]
    out = [res[k] for k in order]
    if vectors:
        return out, Y[:, keep[order]]
    return out


def _diag(A):
    return A.diagonal() if sp.issparse(A) else np.diag(A)


def _sparse_mu(K, C, M, shift, k):
    """The k eigenvalues mu of largest modulus of (A - shift B)^-1 B (and vectors), by ARPACK with a sparse LU."""
    import scipy.sparse.linalg as spla

    from .linear import _arpack

    n = K.shape[0]
    K, C, M = (sp.csr_matrix(x) for x in (K, C, M))
    I = sp.identity(n, format="csr")
    A = sp.bmat([[None, I], [-K, -C]], format="csc")
    B = sp.bmat([[I, None], [None, M]], format="csr")
    lu = spla.splu((A - shift * B).tocsc())
    op = spla.LinearOperator((2 * n, 2 * n), matvec=lambda x: lu.solve(B @ x), dtype=float)
    return _arpack(spla.eigs, op, k=k, which="LM", v0=np.ones(2 * n), ncv=min(2 * n, max(2 * k + 1, 40)))


def flowing_modes(model, count=20, about="initial", vectors=False, method="auto"):
    """The ``count`` lowest modes of the flowing tube (see the module notes); :func:`flowing_linearization`."""
    lin = flowing_linearization(model, about)
    res = first_order_modes(lin["K"], lin["C"], lin["M"], count, vectors, method=method)
    if vectors and lin["Z"] is not None:  # the constrained rod: displacements q = Z y
        return res[0], lin["Z"] @ res[1]
    return res


