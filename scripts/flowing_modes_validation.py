"""The measured thresholds of ``varint modes`` on tubes conveying fluid (varint/analysis/flowing_modes.py) against
varint/exact/pipe_stability.py (Païdoussis eq. 3.70 by Galerkin, 40 beam modes), at 20 / 40 / 80 elements, with the
order of the error: the table of docs/validation.md ("Tubes conveying fluid").

The pipes are those of tests/test_flowing_modes.py (L = 1, EI = 1, M + m = 1, EA = kGA = 1e7, planar rod); the
thresholds come from varint.analysis.thresholds.threshold (bisection on the largest growth rate over fluid.velocity).

    python scripts/flowing_modes_validation.py [--nodes 21,41,81]
"""

import argparse
import sys
import time

import numpy as np


from varint.scene.standard import pipe_scene_text as pipe_text  # noqa: E402

from varint.exact import pipe_stability as ps  # noqa: E402
from varint.analysis.thresholds import threshold  # noqa: E402

CASES = [  # (name, ends, beta, gamma)
    ("pinned-pinned", ("pinned", "pinned"), 0.5, 0.0),
    ("clamped-clamped", ("clamped", "clamped"), 0.5, 0.0),
    ("cantilever", ("clamped", "free"), 0.1, 0.0),
    ("cantilever", ("clamped", "free"), 0.2, 0.0),
    ("cantilever", ("clamped", "free"), 0.5, 0.0),
    ("cantilever", ("clamped", "free"), 0.8, 0.0),
    ("hanging cantilever", ("clamped", "free"), 0.2, 10.0),
    ("hanging cantilever", ("clamped", "free"), 0.5, 10.0),
    ("hanging, Païdoussis Table 3.4", ("clamped", "free"), 0.23e-3, 61.1),
    ("hanging, Païdoussis Table 3.4", ("clamped", "free"), 2.03e-3, 42.4),
]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--nodes", default="21,41,81")
    args = ap.parse_args()
    nodes = [int(x) for x in args.nodes.split(",")]
    print("| case | beta | gamma | truth u_c (omega_c) | " + " | ".join(f"{n - 1} el.: u_c err (omega err)" for n in nodes)
          + " | order u_c |")
    print("|---|---|---|---|" + "---|" * len(nodes) + "---|")
    for name, ends, beta, gamma in CASES:
        uc, om, kind = ps.critical_flow_velocity(beta, "-".join(ends), gamma=gamma)
        errs, cells = [], []
        for n in nodes:
            t0 = time.perf_counter()
            text = pipe_text(ends, beta, 1.0, n, 2, gamma)
            r = threshold(text, 0.9 * uc / np.sqrt(beta), 1.1 * uc / np.sqrt(beta), count=8,
                          about="static" if gamma else "initial", rtol=1e-7)
            u = r["value"] * np.sqrt(beta)
            e = u / uc - 1
            errs.append(e)
            ef = r["frequency"] / om - 1 if om else None
            cells.append(f"{e:+.2e}" + (f" ({ef:+.2e})" if ef is not None else " (0)"))
            print(f"#   {name} beta {beta} gamma {gamma} {n - 1} el.: u {u:.8g} in {time.perf_counter() - t0:.1f} s "
                  f"({r['evaluations']} evaluations)", file=sys.stderr)
        order = np.log2(abs(errs[-2] / errs[-1])) if len(errs) > 1 else float("nan")
        truth = f"{uc:.6g} ({om:.5g}, {kind})"
        print(f"| {name} | {beta} | {gamma:g} | {truth} | " + " | ".join(cells) + f" | {order:.2f} |")


if __name__ == "__main__":
    main()
