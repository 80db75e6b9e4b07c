"""Cost of the rod's Newton Jacobian and of a rod step: exact element Jacobian against the 0.1
finite-difference one, side by side in one run (docs/performance.md, "Exact rod Jacobian").

* one Jacobian: ``sim.stepper.action.jacobian`` (the rod term's element blocks by complex step of the analytic
  element gradient, assembled) against :func:`jacobian_fd` (colour-grouped central differences of
  the residual, the 0.1 path, rebuilt here with ``varint.terms.rod.banded_jacobian``), and one residual (analytic gradient against the complex step of the
  whole L_d), at 10 and 100 elements, planar and 3D;
* a rod step at 100 elements: the 0.1 path (complex-step residual, finite-difference Jacobian)
  against the exact one, on the planar PyElastica cantilever (scripts/bench_pyelastica.py's section,
  released from a bent shape) and a 3D free rod tumbling (tests/test_rod.py's tumbling case, 100 elements).

Run alone (2 cores shared otherwise distort the timings):  python scripts/bench_rod_jacobian.py
"""

from __future__ import annotations

import time

import numpy as np

import varint.run.simulation as vs
from varint import Simulation, build_model
from varint.scene.standard import ROD_SPIN, ROD_STIFF_SECTION, rod_scene, solid_section
from varint.terms.rod import RATE_REFRESH_ROD, banded_jacobian


def best_of(fn, repeat=5):
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def jacobian_fd(step, q0, p0, z):
    """Colour-grouped central differences of the step residual (the 0.1 Jacobian, kept for comparison):
    ``banded_jacobian`` on the residual spread over all (N+1, 6) rod components (zero off the mask), as
    in tests/test_rod_exact_derivatives.py.  Rod-only models: the rod's unknowns are all of z."""
    m = step.model
    mask = m.rod.mask

    def full(zz):
        R = np.zeros((m.N + 1, 6))
        R[mask] = step.residual(q0, p0, zz)
        return R

    return banded_jacobian(full, z, mask, m.ds)


def old_path(sim):
    """Turn a simulation into the 0.1 one: complex-step residual, finite-difference Jacobian.

    The rod term reads ``model.rod.derivative`` (an instance attribute overrides the method) and the
    stepper's Newton calls ``sim.stepper.action.jacobian(q0, z)``; the residual is p_n + D1 L_d + f^-, so its
    Jacobian does not depend on p_n, which is read from the state the step starts from, as 0.1 did."""
    rod = sim.model.rod
    rod.derivative = rod.derivative_complex_step
    sim.stepper.action.jacobian = lambda q0, z: jacobian_fd(sim.stepper.action, q0, sim.state.p, z)
    return sim


def scenes(n_el):
    return {
        "planar cantilever": rod_scene(nodes=n_el + 1, dimension=2, h=2e-4, section=solid_section(),
                                       ends=("clamped", "free"), initial={"curvature": [0.0, 0.0, 0.5]}),
        "3D tumbling": rod_scene(nodes=n_el + 1, h=2e-3, section=ROD_STIFF_SECTION, initial=ROD_SPIN, length=1.0),
    }


def jacobian_table():
    rows = []
    for n_el in (10, 100):
        for name, scene in scenes(n_el).items():
            sim = Simulation(build_model(scene))
            sim.step()
            step, q0, p0 = sim.stepper.action, sim.state.q, sim.state.p
            z = sim.stepper.predictor()  # the Newton start of the next step (last step's b, xi)
            step.jacobian(q0, z), jacobian_fd(step, q0, p0, z)  # compile
            t_new = best_of(lambda: step.jacobian(q0, z))
            t_old = best_of(lambda: jacobian_fd(step, q0, p0, z))
            t_res = best_of(lambda: step.residual(q0, p0, z))
            pt = step.point(q0, z)
            rod = sim.model.rod
            Lam, r, xi, r1 = pt.Lam_n, pt.r_n, pt.xi, pt.r_1
            t_cs = best_of(lambda: rod.derivative_complex_step(sim.h, Lam, r, xi, r1, 0))
            t_an = best_of(lambda: rod.derivative(sim.h, Lam, r, xi, r1, 0))
            rows.append((name, n_el, sim.model.nz, t_old, t_new, t_cs, t_an, t_res))
    print("| rod | elements | unknowns | FD Jacobian ms | exact Jacobian ms | ratio | CS gradient us | analytic gradient us | ratio | exact Jacobian / residual |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, n_el, nz, t_old, t_new, t_cs, t_an, t_res in rows:
        print(f"| {name} | {n_el} | {nz} | {1e3 * t_old:.3g} | {1e3 * t_new:.3g} | {t_old / t_new:.0f} | {1e6 * t_cs:.3g} | "
              f"{1e6 * t_an:.3g} | {t_cs / t_an:.1f} | {t_new / t_res:.1f} |")


def step_table(steps=200):
    print()
    print("| rod (100 elements) | path | ms per step | Newton iterations / step | Jacobians / step | 0.1 / this |")
    print("|---|---|---|---|---|---|")
    paths = (("0.1: CS residual, FD Jacobian, refresh rate 0.5", True, 0.5), ("exact, refresh rate 0.5", False, 0.5),
             (f"exact, refresh rate {RATE_REFRESH_ROD} (default)", False, RATE_REFRESH_ROD))
    # the stepper reads its own binding of the rate (imported from varint.terms.rod): swap that one
    default_rate = vs.RATE_REFRESH_ROD
    for name, scene in scenes(100).items():
        out = {}
        for path, old, rate in paths:
            vs.RATE_REFRESH_ROD = rate
            sim = Simulation(build_model(scene))
            if old:
                old_path(sim)
            sim.step()  # compile, first Jacobian
            it0, jac0 = sim.stats.total_iterations, sim.stats.total_jacobians
            t0 = time.perf_counter()
            for _ in range(steps):
                sim.step()
            wall = (time.perf_counter() - t0) / steps
            out[path] = (wall, (sim.stats.total_iterations - it0) / steps, (sim.stats.total_jacobians - jac0) / steps,
                         sim.monitors()["energy"])
        vs.RATE_REFRESH_ROD = default_rate
        w_old = out[paths[0][0]][0]
        for path, (w, i, j, _) in out.items():
            print(f"| {name} | {path} | {1e3 * w:.3g} | {i:.2f} | {j:.3f} | {w_old / w:.1f} |")
        print(f"<!-- {name}: energy after {steps} steps: " + ", ".join(f"{v[3]:.15g}" for v in out.values()) + " -->")


def noise_table():
    """How far the 0.1 finite-difference stiffness moves the lowest w^2 of a slender cantilever: Rayleigh
    quotients of the finite-difference and exact stiffness on the lowest modes of the exact one (found
    by Cholesky of the exact K: the largest eigenvalues of K^-1 are the accurate ones)."""
    import scipy.linalg as sla

    from varint.model.statics import force_jacobian, force_map, lumped_mass

    print()
    print("| cantilever, 100 elements | L/r | entry noise of the FD stiffness | shift of w1^2 | shift of w2^2 | shift of w3^2 |")
    print("|---|---|---|---|---|---|")
    for dim in (2, 3):
        for rad in (1e-2, 1e-3, 1e-4, 1e-5, 1e-6):
            model = build_model(rod_scene(nodes=101, dimension=dim, section=solid_section(rad=rad), ends=("clamped", "free")))
            rod = model.rod
            M = lumped_mass(rod)[rod.mask]
            Kfd = -banded_jacobian(force_map(rod, rod.Lam0, rod.r0), np.zeros(rod.nz), rod.mask, rod.ds).toarray()
            Kex = -force_jacobian(rod, rod.Lam0, rod.r0).toarray()
            Kfd, Kex = 0.5 * (Kfd + Kfd.T), 0.5 * (Kex + Kex.T)
            Mh = np.sqrt(M)
            C = Mh[:, None] * sla.cho_solve(sla.cho_factor(Kex), np.diag(Mh))
            _, Y = sla.eigh(0.5 * (C + C.T))
            V = Y[:, ::-1][:, : 3 if dim == 2 else 6: 1 if dim == 2 else 2] / Mh[:, None]
            shift = [(v @ Kfd @ v) / (v @ Kex @ v) - 1 for v in V.T]
            print(f"| {'planar' if dim == 2 else '3D'} | {1 / rad:.0e} | {np.max(np.abs(Kfd - Kex)) / np.max(np.abs(Kex)):.1e} | "
                  + " | ".join(f"{x:+.1e}" for x in shift) + " |")


if __name__ == "__main__":
    jacobian_table()
    step_table()
    noise_table()
