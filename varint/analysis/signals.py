"""Reading rates and frequencies off time series of a run (the measures the validation cases are scored by)."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["peak_growth_rate", "zero_crossing_frequency", "two_frequency_fit", "dominant_frequency", "drift_statistics",
           "dominant_wavenumber_index", "observed_orders", "nearest"]


def peak_growth_rate(t, y, skip=1):
    """Growth rate [1/time] of an oscillation from the peaks of |y(t)|: the slope of a least-squares line through
    log |y| at the peaks, leaving out the first ``skip`` (a kick's transient).  Positive: growing.  Raises
    ValueError with fewer than three peaks to fit."""
    a = np.abs(np.asarray(y, dtype=float))
    t = np.asarray(t, dtype=float)
    pk = [i for i in range(1, len(a) - 1) if a[i] >= a[i - 1] and a[i] > a[i + 1]][skip:]
    if len(pk) < 3:
        raise ValueError(f"too few peaks ({len(pk)} after skipping {skip}) to fit a growth rate")
    return float(np.polyfit(t[pk], np.log(a[pk]), 1)[0])


def zero_crossing_frequency(t, y):
    """Angular frequency from the spacing of the first and last zero crossings of y(t) (linear interpolation).

    y must oscillate about zero (no mean is subtracted: over a non-integer number of periods
    the sample mean of a pure cosine is not zero and would bias the crossings).
    """
    idx = np.nonzero(np.sign(y[:-1]) * np.sign(y[1:]) < 0)[0]
    tc = t[idx] - y[idx] * (t[idx + 1] - t[idx]) / (y[idx + 1] - y[idx])
    return math.pi * (len(tc) - 1) / (tc[-1] - tc[0])


def two_frequency_fit(c, h):
    """The two complex frequencies omega of c(t_n) = A exp(-i omega_1 t) + B exp(-i omega_2 t), sampled every ``h``
    (linear prediction), sorted by real part."""
    A = np.stack([c[1:-1], c[:-2]], 1)
    a = np.linalg.lstsq(A, c[2:], rcond=None)[0]
    z = np.roots([1.0, -a[0], -a[1]])
    return tuple(sorted((complex(1j * np.log(x) / h) for x in z), key=lambda w: w.real))


def dominant_frequency(c, h):
    """The complex frequency of c(t_n) = A exp(-i omega t), sampled every ``h`` (one-term linear prediction): a
    growing wave once the decaying one has died out."""
    a = np.vdot(c[:-1], c[1:]) / np.vdot(c[:-1], c[:-1])
    return complex(1j * np.log(a) / h)


def drift_statistics(t, err):
    """Of an error series err(t): its largest magnitude, the mean of each quarter after the first, and the trend
    fitted over the last three quarters (the fitted line's change over them).  A secular drift makes the quarter
    means walk and the trend approach the bound."""
    q = len(err) // 4
    means = [float(np.mean(err[i * q:(i + 1) * q])) for i in range(1, 4)]
    slope = np.polyfit(t[q:], err[q:], 1)[0]
    return float(np.max(np.abs(err))), means, float(slope * (t[-1] - t[q]))


def dominant_wavenumber_index(v):
    """Index of the dominant wavenumber of a periodic nodal vector (its largest Fourier coefficient but the mean)."""
    F = np.abs(np.fft.rfft(v))
    F[0] = 0.0
    return int(np.argmax(F))


def observed_orders(errors):
    """Observed orders log2(e_i / e_{i+1}) of errors at successive halvings of a step or a spacing."""
    e = np.asarray(errors)
    return np.log2(e[:-1] / e[1:])


def nearest(values, targets):
    """For each target, the value nearest to it."""
    values = np.asarray(values)
    return np.array([values[np.argmin(np.abs(values - t))] for t in targets])
