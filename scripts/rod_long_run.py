"""Long run of the free tumbling rod outside CI: momenta, energy and frame orthogonality over many steps.

Run:  python scripts/rod_long_run.py [STEPS] [--at-rest] [--h H] [--measure paper]
      (default 10^6 steps of 0.01 s, ~1-2 ms each; --at-rest: the same spin with the centre of mass
      at rest; --measure paper: the paper's |Gamma| measure)
Prints the worst deviations and the energy drift per decade of steps.  The rod drifts at 0.37 m/s
(10^6 steps: 3.7 km from the origin), so the angular momentum about the origin carries |r| times the
round-off of P (a lever arm); the angular momentum about the centre of mass is printed too.
"""

import time

import numpy as np

from varint import Simulation, build_model
from varint.scene.standard import tumbling_scene


def main(steps, at_rest=False, h=1e-2, measure="reference"):
    model = build_model(tumbling_scene(h=h, at_rest=at_rest, measure=measure))
    sim = Simulation(model)
    sim.step()
    m1 = sim.monitors()
    P, J, E = m1["linear_momentum"], m1["angular_momentum"], m1["energy"]
    Jc = m1["angular_momentum_cm"]
    # with the centre of mass at rest P = 0: measure it against the momentum of the motion, sum |p_j|
    p_sum = np.sum(np.linalg.norm(sim.state.p[model.rod_p][: 3 * (model.N + 1)].reshape(-1, 3), axis=1))
    P_scale = np.linalg.norm(P) if np.linalg.norm(P) > 1e-6 * p_sum else p_sum
    worst = {"linear": 0.0, "angular": 0.0, "angular_cm": 0.0, "orthogonality": 0.0}
    marks = {10 ** k for k in range(2, 6)} | set(range(100_000, steps + 1, 100_000)) | set(range(2000, min(steps, 20_000) + 1, 2000))
    band = []
    t0 = time.perf_counter()
    for n in range(2, steps + 1):
        sim.step()
        mo = sim.monitors()
        worst["linear"] = max(worst["linear"], np.max(np.abs(mo["linear_momentum"] - P)) / P_scale)
        worst["angular"] = max(worst["angular"], np.max(np.abs(mo["angular_momentum"] - J)) / np.linalg.norm(J))
        worst["angular_cm"] = max(worst["angular_cm"], np.max(np.abs(mo["angular_momentum_cm"] - Jc)) / np.linalg.norm(Jc))
        worst["orthogonality"] = max(worst["orthogonality"], mo["frame_orthogonality"])
        band.append(mo["energy"] / E - 1)
        if n in marks or n == steps:
            b = np.array(band)
            print(f"steps {n:>8d}  wall {time.perf_counter() - t0:8.1f} s  energy dev: max {np.max(np.abs(b)):.3e}, "
                  f"mean of the last tenth {np.mean(b[-max(1, len(b) // 10):]):+.3e}  "
                  f"momenta {worst['linear']:.2e} / {worst['angular']:.2e} (about the centre of mass {worst['angular_cm']:.2e})  orthogonality {worst['orthogonality']:.2e}  "
                  f"Newton fallbacks {sim.stats.fallbacks}", flush=True)


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("steps", nargs="?", type=int, default=1_000_000)
    ap.add_argument("--at-rest", action="store_true", help="the same spin with the centre of mass at rest")
    ap.add_argument("--h", type=float, default=1e-2, help="time step (default 0.01 s: h|omega| = 0.53)")
    ap.add_argument("--measure", choices=("reference", "paper"), default="reference")
    a = ap.parse_args()
    main(a.steps, a.at_rest, a.h, a.measure)
