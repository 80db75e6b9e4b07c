"""The traveling shock's Mach number against its strength, M(z), beside the classical normal shock.

The paper's rubber tube (R0 = 5 cm, beta1 = 1.14e5 N, beta2 = 8.37e5 N/m^2, a = 0.4782 kg/m, air at
1 atm ahead; docs/theory.md §11) over its admissible speeds, and the same tube with a wall 10^4 times
stiffer (beta2 x 1e4, which tends to the rigid tube: the classical curve
M = sqrt(1 + (gamma + 1) z / (2 gamma))).  Prints a table and writes docs/shock_mach.png.

Run:  python scripts/shock_mach_curve.py
"""

from pathlib import Path

import numpy as np

from varint.exact import shocks as S

PAPER = dict(R0=0.05, beta1=1.14e5, beta2=8.37e5, a=0.4782, p_ext=101325.0, rho=1.225, p=101325.0, gamma=1.4)
OUT = Path(__file__).resolve().parent.parent / "docs" / "shock_mach.png"


def curve(tube, n=40):
    lo, hi = S.speed_range(tube)
    speeds = lo + (hi - lo) * (1 - np.cos(np.linspace(0.02, 0.98, n) * np.pi / 2))  # denser near c_min
    z, M = [], []
    for c in speeds:
        ts = S.traveling_shock(tube, c)
        z.append(ts.strength)
        M.append(ts.mach)
    return (lo, hi), np.array(z), np.array(M)


def main():
    paper = S.make_tube(**PAPER)
    stiff = S.make_tube(**dict(PAPER, beta2=PAPER["beta2"] * 1e4))
    rows = []
    fig_data = []
    for name, tube in (("paper's rubber tube", paper), ("wall x 1e4 stiffer", stiff)):
        (lo, hi), z, M = curve(tube)
        fig_data.append((name, z, M))
        M_cl = S.classical_mach(z, PAPER["gamma"])
        rows.append((name, lo, hi, z.min(), z.max(), float(np.max(np.abs(M / M_cl - 1)))))
        print(f"\n{name}: admissible speeds {lo:.3f} < c < {hi:.3f} m/s")
        print("| c [m/s] | z | M | classical M(z) |\n|---|---|---|---|")
        for k in range(0, len(z), 8):
            print(f"| {M[k] * lo:.2f} | {z[k]:.4f} | {M[k]:.4f} | {M_cl[k]:.4f} |")
    print("\n| tube | c_min | c_max | z range | max |M / M_classical - 1| |\n|---|---|---|---|---|")
    for name, lo, hi, zmin, zmax, dev in rows:
        print(f"| {name} | {lo:.2f} | {hi:.2f} | {zmin:.3f}–{zmax:.3f} | {dev:.2e} |")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 4), constrained_layout=True)
    zz = np.linspace(0.0, max(d[1].max() for d in fig_data) * 1.05, 200)
    ax.plot(zz, S.classical_mach(zz, PAPER["gamma"]), "k-", lw=1, label="classical normal shock")
    for (name, z, M), style in zip(fig_data, ("o-", "s--")):
        ax.plot(z, M, style, ms=3, lw=1, label=f"traveling shock, {name}")
    ax.set_xlabel("strength z = (p₊ − p₋)/p₋")
    ax.set_ylabel("Mach number M = c / c_s")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.savefig(OUT, dpi=120)
    print(f"\nwrote {OUT}")


if __name__ == "__main__":
    main()
