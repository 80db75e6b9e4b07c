"""Reading rates and frequencies off time series of a run (the measures the validation cases are scored by)."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["peak_growth_rate", "zero_crossing_frequency"]


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
