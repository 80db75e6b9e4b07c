"""Long energy run of the closed dynamic-wall tube with 10 % pressure sloshing, outside the test suite.

Run:  python scripts/slosh_long_run.py [STEPS]      (default 10^5 midpoint steps of h = 1e-5 s, 1 s,
      ~170 wave periods; about 40 s on one core)
The test suite runs the first 10^4 steps of the same scene (tests/test_conservation.py, scripts/_runs.py); this prints
what only the long run shows: the largest relative energy error, the mean error of each quarter after
the first and the trend fitted over the last three quarters (a secular drift would make the quarter
means walk and the trend approach the bound), the mass deviation and the number of Jacobians.
Exit status 1 if the run breaks the bound 1.5e-9 or shows a drift above a tenth of its bound.
"""

import sys
import time

from varint.analysis.signals import drift_statistics

from _runs import BOUND_10PCT, sloshing_record


def main(steps):
    t0 = time.perf_counter()
    sim, t, err, m0 = sloshing_record(steps, every=50)
    wall = time.perf_counter() - t0
    bound, means, trend = drift_statistics(t, err)
    mass = abs(sim.monitors()["mass"] / m0 - 1)
    print(f"steps {steps}  wall {wall:.1f} s  max relative energy error {bound:.3e} (bound {BOUND_10PCT:.1e})")
    print("mean error per quarter after the first: " + ", ".join(f"{m:.3e}" for m in means)
          + f"  (spread {max(means) - min(means):.2e})")
    print(f"trend over the last three quarters {trend:+.2e}  mass deviation {mass:.1e}  "
          f"Jacobians {sim.stats.total_jacobians}  Newton iterations per step {sim.stats.total_iterations / steps:.2f}")
    ok = bound < BOUND_10PCT and max(means) - min(means) < 0.1 * bound and abs(trend) < 0.1 * bound
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main(int(sys.argv[1]) if len(sys.argv) > 1 else 100_000))
