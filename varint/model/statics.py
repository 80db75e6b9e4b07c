"""Statics and steady rotations of the rod (docs/theory.md §9).

* :func:`static_equilibrium` — Newton on SE(3)^(N+1) for the minimum of the discrete potential, with
  load continuation; with ``spin``, the steady rotation (shape at rest in the spinning frame).
* :func:`force_jacobian`, :func:`rotating_frame_kinetics`, :func:`lumped_mass` — the stiffness, the kinetics in a
  spinning frame and the mass that the modes (:mod:`varint.analysis.linear.rod_modes`) are built from.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import scipy.sparse as sp

from ..errors import SolverError
from ..lattice.lie import cay, hat

__all__ = ["static_equilibrium", "load_continuation", "rotating_frame_kinetics", "check_rotating_base", "lumped_mass",
           "turn_to_nearest_principal_axis", "rod_part", "refuse_constrained", "potential_gradient", "force_map",
           "force_jacobian", "retract", "tube_static"]


def rod_part(model):
    """The rod part of a model (its r, Lambda blocks); a part is accepted as it is."""
    return model.rod if hasattr(model, "rod") else model


def refuse_constrained(rod, what):
    """Statics and modes here know the stretch-shear energy, not the constraint that replaces it."""
    if rod.constrained:
        from ..errors import VarintError

        raise VarintError(f"{what} of the inextensible, unshearable rod (rod.constraint) are not available in this "
                          "version (they need the constraint in the static Newton and a constrained eigenproblem)")


def potential_gradient(model, Lam, r, load_factor=1.0):
    """d(-U)/d(dr, sigma) of the potential at a configuration (N+1, 6), including the tip torque."""
    model = rod_part(model)
    xi = np.zeros_like(r)
    # with r_1 = r_n and xi = 0 the step Lagrangian is -h U(config): take h = 1 and sum both levels
    g = (model.derivative(1.0, Lam, r, xi, r, level=0, load_factor=load_factor)
         + model.derivative(1.0, Lam, r, xi, r, level=1, load_factor=load_factor))
    return g + model.generalised_forces(Lam, load_factor)


def force_map(model, Lam, r, load_factor=1.0, spin=None, centre=None):
    """z -> generalised force -dU/d(dr, sigma) at the retracted configuration, (N+1, 6).

    With ``spin`` the centrifugal force and torque of a steady rotation about the axis through
    ``centre`` are added: the force whose zero is a steady rotation (docs/theory.md §9).
    """
    model = rod_part(model)
    mask = model.mask

    def f(z):
        Lz, rz = retract(Lam, r, z, mask)
        g = potential_gradient(model, Lz, rz, load_factor)
        if spin is not None:
            g = g + rotating_frame_kinetics(model, spin, Lz, rz, centre)[0]
        return g

    return f


def force_jacobian(model, Lam, r, load_factor=1.0, spin=None, centre=None):
    """Exact derivative (nz, nz) of :func:`force_map` at z = 0: the element blocks of the discrete
    potential (complex step of the analytic element gradient, ``RodPart.potential_hessian``) and,
    with ``spin``, the node-local derivative of the centrifugal force and torque b of
    :func:`rotating_frame_kinetics` under Lambda cay(sigma), r + dr:

        d b_r / d dr = m Om^T Om,      d b_sigma / d sigma = hat(I Ob) hat(Ob) - hat(Ob) I hat(Ob),   Ob = Lambda^T Om.
    """
    model = rod_part(model)
    H = model.potential_hessian(Lam, r, load_factor)
    if spin is None:
        return H
    Om = np.asarray(spin, dtype=float)
    W = hat(Om)
    n = model.N + 1
    blocks = np.zeros((n, 6, 6))
    blocks[:, :3, :3] = model.node_mass[:, None, None] * (W.T @ W)
    Ob = np.einsum("nji,j->ni", Lam, Om)
    Wb, WI = hat(Ob), hat(model.node_inertia * Ob)
    blocks[:, 3:, 3:] = WI @ Wb - Wb @ (model.node_inertia[:, :, None] * Wb)
    idx = np.flatnonzero(model.mask.ravel())
    return (H + sp.block_diag(list(blocks)).tocsr()[idx][:, idx]).tocsc()


def static_equilibrium(model, steps=4, tol=1e-10, max_iter=30, spin=None):
    """Minimise the discrete potential by Newton on SE(3)^(N+1) with load continuation.

    Returns (Lambda, r, info).  Increments are applied as Lambda cay(sigma), r + dr; the
    load is applied in ``steps`` equal increments, doubled until every increment converges.
    With ``spin`` (an angular velocity) the equilibrium sought is the *steady rotation*: the shape
    at rest in the frame spinning about the axis through the initial centre of mass, where the
    centrifugal loads (scaled by the load factor, i.e. spin^2) balance the elastic forces.  A free
    spinning rod keeps neutral directions (sliding along and turning about the axis); a tiny
    Levenberg shift of the Hessian (1e-10 of its diagonal) leaves them at rest.
    """
    model = rod_part(model)
    if model.constrained and spin is not None:
        refuse_constrained(model, "steady rotations")
    import scipy.sparse.linalg as spla

    mask = model.mask
    scale = np.where(np.nonzero(mask.ravel())[0] % 6 < 3, model.ds, 1.0)
    centre = model.centre_of_mass(model.r0)
    if spin is not None:
        spin = np.asarray(spin, dtype=float)
        check_rotating_base(model, spin)
    elif model.free:
        raise SolverError("static equilibrium: with both rod.ends free the rod can move rigidly, so it has no "
                          "unique static equilibrium; clamp or pin an end (or give rod.initial.angular_velocity "
                          "for a steady rotation)")
    start = (model.Lam0.copy(), model.r0.copy())
    if spin is not None and model.free:
        start = turn_to_nearest_principal_axis(model, *start, spin)
    def newton_step(state, lf):
        """One Newton update at load factor ``lf``: (new state, converged), or (state, None) when singular."""
        Lam, r, lam = state
        spin_k = None if spin is None else math.sqrt(lf) * spin
        g = force_map(model, Lam, r, lf, spin_k, centre)(np.zeros(model.nz))[mask]
        H = force_jacobian(model, Lam, r, lf, spin_k, centre)
        if spin is not None:
            H = H + sp.diags(1e-10 * np.max(np.abs(H.diagonal())) * np.ones(model.nz))
        if model.constrained:
            # KKT of min U subject to Gamma = chi: the force balance with the constraint forces and
            # the constraint itself, by Newton on the saddle matrix [[dF/dz, -ds G^T], [G, 0]]
            from ..terms.rod_constraint import constraint_static

            c, G, Fc, Hc = constraint_static(model, Lam, r, lam)
            K = sp.bmat([[H + Hc, -model.ds * G.T], [G, None]]).tocsc()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", spla.MatrixRankWarning)
                d = -spla.spsolve(K, np.concatenate([g + Fc, c]))
            dz = d[:model.nz]
            if np.all(np.isfinite(d)):
                lam = lam.copy()
                lam[:, :model.ncomp] += d[model.nz:].reshape(model.N, model.ncomp)
        else:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", spla.MatrixRankWarning)  # singular: dz is not finite, handled below
                dz = -spla.spsolve(H.tocsc(), g)
        if not np.all(np.isfinite(dz)):
            return state, None
        Lam, r = retract(Lam, r, dz, mask)
        return (Lam, r, lam), bool(np.max(np.abs(dz) / scale) < tol)

    # lam: the inextensible rod's element forces (docs/theory.md §9a)
    (Lam, r, lam), n_steps, iters = load_continuation(lambda: (start[0].copy(), start[1].copy(), np.zeros((model.N, 3))),
                                                      newton_step, steps, max_iter)
    info = {"load_steps": n_steps, "iterations": iters}
    if model.constrained:
        info["element_forces"] = lam.copy()
    if spin is not None:
        # a spin about no principal axis has no steady rotation near the given shape: the rod
        # was turned as a whole to one that has (reported, since it changes the scene)
        c0, c1 = model.r0[-1] - model.r0[0], r[-1] - r[0]
        cosang = np.dot(c0, c1) / (np.linalg.norm(c0) * np.linalg.norm(c1))
        info["turned_deg"] = float(np.degrees(np.arccos(np.clip(cosang, -1.0, 1.0))))
    return Lam, r, info


def load_continuation(start, newton_step, steps=4, max_iter=30):
    """Load continuation shared by the statics (the rod's, the coupled tube's): the load applied in ``steps``
    equal increments, each solved by repeated ``newton_step(state, load_factor) -> (state, converged)``
    (``converged`` None: a singular or non-finite update), from ``start()``; the number of increments is
    doubled until every one converges.  Returns (state, increments, Newton iterations)."""
    n_steps = steps
    while True:
        state, ok, iters = start(), True, 0
        for k in range(1, n_steps + 1):
            lf = k / n_steps
            for _ in range(max_iter):
                state, done = newton_step(state, lf)
                if done is None:
                    ok = False
                    break
                iters += 1
                if done:
                    break
            else:
                ok = False
            if not ok:
                break
        if ok:
            return state, n_steps, iters
        if n_steps >= 256:
            raise SolverError("static equilibrium: Newton did not converge even with 256 load steps")
        n_steps *= 2


def turn_to_nearest_principal_axis(model, Lam, r, spin):
    """Turn a free rod rigidly, about its centre of mass, by the smallest rotation that makes ``spin``
    one of its principal axes of inertia (the lumped masses and section inertias).

    A free body is in steady rotation only about a principal axis; Newton started from a shape
    spun about no principal axis wanders to *some* steady rotation (the tumbling example's chord
    ended along the spin axis, 75 degrees away).  Starting from the nearest principal alignment
    makes the result the steady rotation closest to the given shape.  Among degenerate principal
    axes (a straight rod's transverse ones) the one nearest to the spin is taken.
    """
    model = rod_part(model)
    m = model.node_mass
    rc = model.centre_of_mass(r)
    rho = r - rc
    J = (np.sum(m * np.sum(rho * rho, 1)) * np.eye(3) - (m[:, None] * rho).T @ rho
         + np.einsum("nik,nk,njk->ij", Lam, model.node_inertia, Lam))
    vals, vecs = np.linalg.eigh(J)
    w = spin / np.linalg.norm(spin)
    best, target = 0.0, w
    for lam in vals:  # each eigenspace: project the spin onto it, keep the largest projection
        V = vecs[:, np.abs(vals - lam) <= 1e-8 * np.max(np.abs(vals))]
        p = V @ (V.T @ w)
        n = float(np.linalg.norm(p))
        if n > best + 1e-12:
            best, target = n, p / n
    axis = np.cross(target, w)
    s, c = np.linalg.norm(axis), float(np.dot(target, w))
    if s < 1e-15:
        return Lam, r
    K = hat(axis / s)
    Q = np.eye(3) + s * K + (1.0 - c) * K @ K  # Rodrigues: turns target onto the spin axis
    return Q @ Lam, rc + rho @ Q.T


def retract(Lam, r, z, mask):
    u = np.zeros(mask.shape)
    u[mask] = z
    return Lam @ cay(u[:, 3:]), r + u[:, :3]


def rotating_frame_kinetics(model, Omega, Lam, r, centre=None):
    """Kinetic energy of the lumped rod seen from a frame spinning at Omega about the centre of mass.

    With r = r_c + R(t) rho, Lambda = R(t) Lambda~ (R = exp(t Omega^)), the semi-discrete kinetic
    energy T = sum_j 1/2 m_j |Omega x rho_j + rho_j'|^2 + 1/2 w_j^T I_j w_j, w_j = Lambda~_j^T Omega
    + (body velocity of Lambda~_j), is autonomous.  Expanded to second order in the perturbation
    rho = rho_0 + dr, Lambda~ = Lambda~_0 cay(sigma) (docs/theory.md §9, "Modes of a spinning rod"):

        T = b.q + q'^T C q + 1/2 q'^T M q' + 1/2 q^T H q + (q-independent),   q = (dr, sigma) per node.

    Returns per-node blocks ``b`` (N+1, 6), ``C`` and ``H`` (N+1, 6, 6); M is :func:`lumped_mass`.
    ``centre``: a point of the spin axis (default: the centre of mass of ``r``).
    """
    model = rod_part(model)
    m, inertia = model.node_mass, model.node_inertia
    Omega = np.asarray(Omega, dtype=float)
    rc = model.centre_of_mass(r) if centre is None else np.asarray(centre, dtype=float)
    W = hat(Omega)
    n = model.N + 1
    b = np.zeros((n, 6))
    C = np.zeros((n, 6, 6))
    H = np.zeros((n, 6, 6))
    # translation: 1/2 m |Omega x (rho_0 + dr) + dr'|^2
    C[:, :3, :3] = m[:, None, None] * W
    H[:, :3, :3] = m[:, None, None] * (W.T @ W)
    b[:, :3] = m[:, None] * ((r - rc) @ (W.T @ W).T)  # centrifugal force
    # rotation: w = cay(sigma)^T Ob + dcay_{-sigma} sigma' = Ob + Ob x sigma + 1/2 sigma x (sigma x Ob) + sigma' - 1/2 sigma x sigma'
    Ob = np.einsum("nji,j->ni", Lam, Omega)  # Lambda^T Omega, the frame's spin seen in each section
    IO = inertia * Ob
    Wb = hat(Ob)
    C[:, 3:, 3:] = inertia[:, :, None] * Wb - 0.5 * hat(IO)
    H[:, 3:, 3:] = (np.swapaxes(Wb, 1, 2) @ (inertia[:, :, None] * Wb)
                    + 0.5 * (IO[:, :, None] * Ob[:, None, :] + Ob[:, :, None] * IO[:, None, :])
                    - np.sum(Ob * IO, axis=1)[:, None, None] * np.eye(3))
    b[:, 3:] = np.cross(IO, Ob)
    return b, C, H


def check_rotating_base(model, Omega):
    """A steady rotation must be one the time-domain rod can perform: one-line error otherwise."""
    model = rod_part(model)
    if model.paper_measure:
        raise SolverError("modes: about a spinning state only with rod.measure = \"reference\" (the paper's measure "
                          "makes the mass depend on the stretch)")
    if np.any(model.force) or np.any(model.torque) or np.any(np.cross(model.g, Omega)):
        raise SolverError("modes: a spinning rod with rod.load or gravity across the spin axis is not in a steady "
                          "rotation (the loads turn relative to it)")
    rc = model.centre_of_mass(model.r0)
    ends = model.scene.rod.ends
    for node, key in ((0, "s0"), (model.N, "sL")):
        kind = getattr(ends, key)
        off_axis = np.linalg.norm(np.cross(Omega, model.r0[node] - rc)) > 1e-12 * model.L * np.linalg.norm(Omega)
        if kind == "clamped" or (kind == "pinned" and off_axis):
            raise SolverError(f"modes: rod.ends.{key} = \"{kind}\" cannot turn with the spin at angular_velocity "
                              f"{[float(x) for x in Omega]}; only pinned ends on the spin axis can")


def lumped_mass(model):
    """Diagonal of the kinetic metric per node and direction (rho A w_j for dr, I w_j for sigma), (N+1, 6)."""
    model = rod_part(model)
    return np.concatenate([np.repeat(model.node_mass[:, None], 3, 1), model.node_inertia], axis=1)


def tube_static(model, tol=1e-11, max_iter=50):
    """The static equilibrium of the straight tube (no [rod]): the labels, radii and multipliers z = (q, lam) with
    B^T grad U(config(z)) = 0 (docs/theory.md §13.10), by Newton with the exact Hessian B^T H B from the initial state.

    A liquid keeps its parcels' volumes (its multipliers are the pressures that hold the wall); a gas finds the
    pressures the wall balances.  Returns (z, info).  Refused in one line: open ends (the fluid flows) and a tube
    without [wall] (its fluid at rest, uniform, is the equilibrium: nothing to solve).  A periodic tube's free
    translation of the labels is held where it is by a Levenberg shift of 1e-10 of the diagonal."""
    import scipy.sparse.linalg as spla

    from ..errors import VarintError

    t = model.tube if hasattr(model, "tube") else model
    if t is None or getattr(model, "rod", None) is not None:
        raise VarintError("static: the straight tube's statics need a scene without [rod]")
    if getattr(t, "open_ends", False):
        raise VarintError("static: with open fluid.ends the fluid flows through the tube: it has no static equilibrium "
                          "(a tube conveying fluid on a [rod] has its steady flowing state)")
    if not t.has_wall:
        raise VarintError("static: a rigid tube without [wall] has nothing to balance (its fluid at rest, uniform, is "
                          "the equilibrium); add a [wall]")
    z = np.concatenate([t.q_init, t.lam_init])
    scale = np.ones(t.nz)
    p_scale = max(abs(float(t.scene.fluid.pressure or 0.0)), 1.0) if t.has_fluid else 1.0
    for name, sl in t.layout.items():
        scale[sl] = {"s": t.L / max(t.M, 1), "R": t.R0}.get(name, p_scale)
    it, err = 0, np.inf
    for it in range(1, max_iter + 1):
        cfg = t.config(z)
        g = t.B.T @ t.gradient(cfg)
        H = (t.B.T @ t.hessian(cfg) @ t.B).tocsc()
        if t.periodic:  # the free translation of every label: held where it is
            H = H + sp.diags(1e-10 * np.maximum(np.abs(H.diagonal()), 1e-300)).tocsc()
        try:
            dz = -spla.spsolve(H, g)
        except RuntimeError as exc:
            raise VarintError(f"static: the tube's stiffness is singular ({exc}); no isolated equilibrium") from None
        if not np.all(np.isfinite(dz)):
            raise VarintError("static: the tube's stiffness is singular; no isolated equilibrium")
        z = z + dz
        err = float(np.max(np.abs(dz) / scale))
        if err <= tol:
            break
    else:
        raise VarintError(f"static: Newton did not converge in {max_iter} iterations (scaled update {err:.3g})")
    return z, {"iterations": it, "error": err}
