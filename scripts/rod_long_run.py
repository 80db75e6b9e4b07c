"""Long run of the free tumbling rod outside CI: momenta, energy and frame orthogonality over many steps.

Run:  python scripts/rod_long_run.py [STEPS]   (default 10^6; ~15 ms per step on the project machine)
Prints the worst deviations and the energy drift per decade of steps.
"""

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

from test_rod import tumbling_model  # noqa: E402

from varint.rod import RodSimulation  # noqa: E402


def main(steps):
    model = tumbling_model()
    sim = RodSimulation(model)
    sim.step()
    m1 = sim.monitors()
    P, J, E = m1["linear_momentum"], m1["angular_momentum"], m1["energy"]
    worst = {"linear": 0.0, "angular": 0.0, "orthogonality": 0.0}
    marks = {10 ** k for k in range(2, 6)} | set(range(100_000, steps + 1, 100_000))
    band = []
    t0 = time.perf_counter()
    for n in range(2, steps + 1):
        sim.step()
        mo = sim.monitors()
        worst["linear"] = max(worst["linear"], np.max(np.abs(mo["linear_momentum"] - P)) / np.linalg.norm(P))
        worst["angular"] = max(worst["angular"], np.max(np.abs(mo["angular_momentum"] - J)) / np.linalg.norm(J))
        worst["orthogonality"] = max(worst["orthogonality"], mo["frame_orthogonality"])
        band.append(mo["energy"] / E - 1)
        if n in marks or n == steps:
            b = np.array(band)
            print(f"steps {n:>8d}  wall {time.perf_counter() - t0:8.1f} s  energy dev: max {np.max(np.abs(b)):.3e}, "
                  f"mean of the last tenth {np.mean(b[-max(1, len(b) // 10):]):+.3e}  "
                  f"momenta {worst['linear']:.2e} / {worst['angular']:.2e}  orthogonality {worst['orthogonality']:.2e}  "
                  f"Newton fallbacks {getattr(sim.stats, 'fallbacks', 0)}", flush=True)


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 1_000_000)
