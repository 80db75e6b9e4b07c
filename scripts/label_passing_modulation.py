"""How much the liquid's inertia on the rod's nodes changes as the labels pass the nodes (docs/theory.md §12,
"Labels passing the nodes").

In the coupled tube the liquid's kinetic energy is sum_k 1/2 mbar_k |Xdot(s_k)|^2 with X(s) = sum_j N_j(s) r_j the
Catmull-Rom centreline (docs/theory.md §10.2).  Its mass matrix on the nodes, M_jl = sum_k mbar_k N_j(s_k) N_l(s_k),
and its gyroscopic (Coriolis) coupling, sum_k mbar_k N_j(s_k) N_l'(s_k) (printed for l = j - 1), depend on where the labels sit in their
elements.  In a uniform flow every label moves at U, so with p parcels per element these matrices are periodic in
time at the label-passing frequency p U / ds: a parametric forcing of every lattice mode.  The continuum has none
(the liquid is uniform along s).  This script prints, per unit length of liquid, the mean of each entry over the
labels' common offset and its swing (max - min) as the offset runs over one parcel length, for p = 1 ... 4.

    python scripts/label_passing_modulation.py
"""

import numpy as np


def catmull_rom(x):
    """The Catmull-Rom cardinal basis function (centred on a node, unit spacing) and its derivative."""
    a = np.abs(x)
    n = np.where(a < 1, 1.5 * a ** 3 - 2.5 * a ** 2 + 1, np.where(a < 2, -0.5 * a ** 3 + 2.5 * a ** 2 - 4 * a + 2, 0.0))
    d = np.sign(x) * np.where(a < 1, 4.5 * a ** 2 - 5 * a, np.where(a < 2, -1.5 * a ** 2 + 5 * a - 4, 0.0))
    return n, d


def modulation(per_element, lag, gyroscopic=False, samples=401):
    """(mean, swing) of sum_k N_0(s_k) N_lag(s_k) (or N_0 N_lag') per unit length, labels at (k + offset) / p."""
    vals = []
    for offset in np.linspace(0.0, 1.0, samples):
        s = (np.arange(-10 * per_element, 10 * per_element) + offset) / per_element
        n0, _ = catmull_rom(s)
        n1, d1 = catmull_rom(s + lag)
        vals.append(np.sum(n0 * (d1 if gyroscopic else n1)) / per_element)
    vals = np.array(vals)
    return vals.mean(), vals.max() - vals.min()


def main():
    print("| parcels per element | M_jj: mean, swing | M_j,j+1: mean, swing | M_j,j+2: mean, swing | "
          "gyroscopic N_j N'_j-1: mean, swing |")
    print("|---|---|---|---|---|")
    for p in (1, 2, 3, 4):
        cells = [modulation(p, lag) for lag in (0, 1, 2)] + [modulation(p, 1, gyroscopic=True)]
        print(f"| {p} | " + " | ".join(f"{m:+.4f}, {w:.2e} ({w / abs(m):.1%})" for m, w in cells) + " |")


if __name__ == "__main__":
    main()
