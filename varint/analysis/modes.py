"""The modes of a scene, as ``varint modes`` and ``varint sweep --analysis modes`` compute them.

One code path for both: the model linearised about the scene's initial state (a spinning rod: about
that rotation, seen from the spinning frame) or, with ``about="static"`` (rods), about its loaded
static equilibrium / steady rotation.
"""

from __future__ import annotations

import numpy as np

from ..errors import VarintError

__all__ = ["scene_modes", "strongest"]


def turned_note(info):
    """How far a steady-rotation search turned the rod, in words ("" when not noticeably)."""
    deg = info.get("turned_deg", 0.0)
    return (f"the rod's end-to-end chord turned by {deg:.1f} deg from the scene's shape (spin about no principal "
            "axis of it)") if deg > 1.0 else ""


def _loads(model):
    """The scene keys of a rod's static loads (empty when there are none)."""
    names = [("rod.load.force", model.force), ("rod.load.torque", model.torque), ("environment.gravity", model.g)]
    return [name for name, v in names if np.any(v)]


def scene_modes(scene, count=20, about="initial", source=None):
    """The ``count`` lowest modes of ``scene``.

    Returns ``{"modes": [{"frequency": rad/s, "growth_rate": 1/s}, ...], "about": about}`` with, when
    they apply, ``"flow"`` (a tube conveying fluid, varint/analysis/flowing_modes.py: its U and Païdoussis' u, beta,
    gamma; growth rates there are signed, negative for a decaying mode), ``"note"`` (modes about an unloaded state of a loaded rod), ``"frame"`` (a spinning rod:
    the frequencies are seen from the spinning frame) and ``"remark"`` (a steady rotation that turned
    the rod).  ``source`` names the scene in messages (default: its path).  Raises :class:`~varint.VarintError`.
    """
    if count < 1:
        raise VarintError(f"modes: -n/--count must be >= 1, got {count}")
    from .linear import modes
    from ..model.model import build_model
    from .rod_modes import rod_modes

    source = source if source is not None else (scene.path or "scene")
    model = build_model(scene)
    d = {"about": about}
    if model.coupled and model.tube.open_ends:
        # docs/theory.md §13.6: a tube conveying fluid, linearised about its steady flow (straight, or the steady
        # state under gravity with --about static)
        from .flowing_modes import first_order_modes, flowing_linearization

        lin = flowing_linearization(model, about)
        d["modes"] = first_order_modes(lin["K"], lin["C"], lin["M"], count)
        par = lin["parameters"]
        d["flow"] = {k: float(par[k]) for k in ("U", "u", "beta", "gamma")}
        if about == "initial" and lin["unbalanced"] > 1e-9:
            why = ", ".join(_loads(model.rod)) or "the steady flow's centrifugal load on a curved tube"
            d["note"] = (f"{source} is not in equilibrium in its initial state ({why}; unbalanced force "
                         f"{lin['unbalanced']:.2g} of a unit strain's): these modes are about the initial state, "
                         "not the steady state; use --about static for that")
        return d
    if model.coupled:
        # docs/theory.md §10.10: the coupled tube's kinetic metric and potential Hessian about its initial state
        from .coupled_modes import coupled_linearization, coupled_static, modes_of_linearization

        configuration = coupled_static(model)[0] if about == "static" else None
        lin = coupled_linearization(model, configuration)
        d["modes"] = modes_of_linearization(model, lin, count)
        loads = _loads(model.rod)
        if about == "initial" and lin["unbalanced"] > 1e-9:
            why = ", ".join(loads) if loads else "e.g. the fluid's pressure against environment.external_pressure"
            d["note"] = (f"{source} is not in equilibrium in its initial state ({why}; unbalanced force "
                         f"{lin['unbalanced']:.2g} of a unit strain's): these modes are about the initial state, "
                         "not a loaded equilibrium")
        return d
    if model.rod is not None:
        spin = model.rod.spin  # rod.initial.angular_velocity
        if about == "static":
            from ..model.statics import static_equilibrium

            # a spinning rod: about its steady rotation (the shape balancing the centrifugal loads)
            Lam, r, info = static_equilibrium(model, spin=spin if np.any(spin) else None)
            res, X = rod_modes(model, count=count, Lam=Lam, r=r, lam=info.get("element_forces"), vectors=True)
            if turned_note(info):
                d["remark"] = f"the steady rotation found has {turned_note(info)}"
        else:
            res, X = rod_modes(model, count=count, vectors=True)
            loads = _loads(model.rod)
            if loads:
                d["note"] = (f"{source} has loads ({', '.join(loads)}): these modes are about the initial, unloaded "
                             "state, not the loaded equilibrium" + ("" if model.rod.free else "; use --about static for that"))
        if np.any(spin):
            d["frame"] = {"angular_velocity": [float(x) for x in spin],
                          "note": "frequencies seen from the frame spinning with the rod (rod.initial.angular_velocity)"}
            label_whirl(res, X, model.rod, spin)
    else:
        t = model.tube
        if t is not None and t.open_ends:
            # docs/theory.md §13.10: the open straight tube about its initial lattice, the flow frozen
            from ..terms.open_ends import open_end_limits

            why = open_end_limits(model)
            if why is not None:
                raise VarintError(f"{source}: modes: {why}")
            if t.outflow != "pressure":
                raise VarintError(f"{source}: modes: fluid.ends.outflow = '{t.outflow}' absorbs the waves that reach it "
                                  "(its modes are damped, not normal modes); the modes with a pressure outlet are those of "
                                  "outflow = 'pressure'")
            if about == "static":
                raise VarintError(f"{source}: --about static: with open fluid.ends the fluid flows; the modes are about "
                                  "the initial lattice (--about initial)")
            U = max(abs(t.U_in), abs(float(model.scene.fluid.velocity)))
            if U > 0.0:
                d["note"] = (f"modes of the open tube about its initial lattice with the flow ({U:.3g} m/s) frozen: the "
                             "mean flow's convection (a shift of relative order Mach^2 for sound) is left out")
        z = None
        if about == "static":
            from ..model.statics import tube_static

            z = tube_static(model)[0]
        try:
            res = modes(model, count=count, z=z)
        except VarintError as exc:
            raise VarintError(f"{source}: {exc}") from None
    d["modes"] = res
    return d


def label_whirl(res, X, rod, spin):
    """Mark the modes of a rod spinning at ``spin`` (rad/s, a vector) as forward or backward whirl, in place.

    A mode q = Re(X e^{i w t}) seen from the spinning frame moves each node on an orbit about the spin axis a; the
    sign of its angular momentum about a, sum_j m_j (u_j v_j' - v_j u_j') = -w sum_j m_j Im(conj(U_j) V_j) (U, V the
    components across a, with a = e_u x e_v), says which way the orbits turn there, at the rate sigma w.  In the lab
    the frame turns at |spin| about a, so the orbits turn at sigma w + |spin|: forward whirl (with the spin) when
    that is positive, backward when negative.  Each mode gets ``"whirl"`` ("forward", "backward", or None for a mode
    without transverse orbits: axial, torsional, a rigid motion) and ``"lab_frequency"`` = |sigma w + |spin|| (rad/s).
    """
    from ..model.statics import lumped_mass

    spin = np.asarray(spin, dtype=float)
    Om = float(np.linalg.norm(spin))
    a = spin / Om
    up = np.array([0.0, 0.0, 1.0]) if abs(a[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    eu = np.cross(up, a)
    eu /= np.linalg.norm(eu)
    ev = np.cross(a, eu)
    mask = np.asarray(rod.mask)
    idx = np.flatnonzero(mask.ravel())
    m = lumped_mass(rod)[mask]
    n_nodes = mask.shape[0]
    for j, mode in enumerate(res):
        mode["whirl"], mode["lab_frequency"] = None, None
        w = mode["frequency"]
        if w <= 0 or mode["growth_rate"] > 0:
            continue
        D = np.zeros((n_nodes, 3), dtype=complex)  # the nodes' complex displacements (translations only)
        W = np.zeros((n_nodes, 3))
        for k, i in enumerate(idx):
            node, c = divmod(int(i), mask.shape[1])
            if c < 3:
                D[node, c] = X[k, j]
                W[node, c] = m[k]
        U, V = D @ eu, D @ ev
        mw = W.max(axis=1)
        L = -float(np.sum(mw * np.imag(np.conj(U) * V)))  # / w: the orbit's sense in the spinning frame
        size = float(np.sum(mw * (np.abs(U) ** 2 + np.abs(V) ** 2)))
        total = float(np.sum(W * np.abs(D) ** 2))
        if size <= 1e-6 * total or abs(L) <= 1e-6 * size:
            continue  # no transverse orbit (axial, torsional) or a planar oscillation (no sense of turning)
        lab = np.sign(L) * w + Om
        mode["whirl"] = "forward" if lab > 0 else "backward"
        mode["lab_frequency"] = float(abs(lab))


def strongest(res):
    """The summary of a modes list that a sweep tabulates.

    ``growth_rate``: the largest growth rate (0 when no mode grows; negative when every mode decays, as a
    tube conveying fluid below its flutter threshold); ``lowest_frequency``: the lowest
    frequency of the modes that do not grow, rigid-body motions (frequency 0, or below 1e-6 of the
    highest listed) left out (NaN when there is none); ``frequency``: the frequency of the fastest
    growing mode, or, when no mode grows, ``lowest_frequency``.
    """
    nan = float("nan")
    grow = max((m["growth_rate"] for m in res), default=nan)
    top = max((m["frequency"] for m in res), default=0.0)
    elastic = [m["frequency"] for m in res if m["growth_rate"] <= 0.0 and m["frequency"] > 1e-6 * top]
    lowest = float(min(elastic)) if elastic else nan
    if grow > 0.0:
        freq = next(m["frequency"] for m in res if m["growth_rate"] == grow)
    else:
        freq = lowest
    return {"growth_rate": float(grow), "frequency": float(freq), "lowest_frequency": lowest}
