"""Statistics of a periodic signal over whole periods: the Strouhal number, mean drag and lift
amplitude / rms of vortex shedding (issue 17 item 5; thesis §4.5.3, Table 4.2).

Input: a time series ``(t[n], y[n])`` as a run records it (``timeseries.csv``: at the output
times, or uniformly every ``output.series_interval``; the samples need not be uniform).  Only the
part after a transient ``t0`` is used, and of it only whole periods of the reference signal (the
lift C_L):

* **Periods** from the upward zero crossings of y - ybar (ybar its mean after ``t0``, then the mean
  over the whole periods found, once more), each located by linear interpolation between the two
  samples around it.  A crossing of a sinusoid sits at its inflection point, where the linear
  interpolant's error is third order in the sampling step: at 20 samples per period the crossing
  times are exact to ~1e-4 of a period, while an FFT bin of a window of W periods is 1/W of the
  frequency (5 % at 20 periods); averaging over the whole periods between the first and the last
  crossing, f = (number of periods) / (t_last - t_first), has no bin quantisation at all.
* **Means** of any column over [t_first, t_last] (whole periods of the lift, hence also of the drag,
  which oscillates at twice the frequency) by the trapezoidal rule, with the end values
  interpolated linearly at the two crossing times.
* **Amplitude**: (max - min) / 2 in each period, the extrema refined by the parabola through the
  largest (smallest) sample and its two neighbours (sub-sample peak, any spacing; at 20 samples per period the
  raw sample maximum of a sinusoid is low by up to 1 - cos(pi / 20) = 1.2 %), averaged over the
  periods; ``rms`` the root mean square of y over the same window (trapezoidal).
* A spectral cross-check: the peak of the Hann-windowed periodogram of y - ybar on the whole
  periods (resampled uniformly), refined by the parabola through the logarithms of the peak bin and
  its neighbours (Gaussian interpolation; its bias for a Hann window is below 2 % of a bin).

What is reported when the signal does not allow it (:func:`whole_period_statistics` returns a
``note`` instead of numbers, never a NaN): no samples after ``t0``; non-finite values; a lift that
does not oscillate above ``floor`` times the flow's scale (the largest |value| of the ``others``
columns, e.g. the drag; 1 without them: a mirror-symmetric flow keeps |C_L| ~ 1e-13 of C_D, a
float32 run ~1e-6: no shedding); fewer than ``min_periods`` whole periods after ``t0``; fewer than
``min_samples`` samples per period (the sampling does not resolve the period), or a gap
in the sampling longer than period / ``min_samples``; crossing intervals that spread by more than
``max_spread`` of their median, or a zero-crossing frequency more than ``max_mismatch`` (or one
spectral bin) away from the spectral one (extra or missing crossings: a ripple at another
frequency, noise); an amplitude that changes by more than ``max_drift`` from the first to the
last whole period (a growing or decaying oscillation: the transient is not over, or the flow does
not shed).  ``rms`` is the rms of the fluctuation y - mean.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

#: Defaults: whole periods needed, samples per period needed, lift floor (round-off level).
MIN_PERIODS = 2
MIN_SAMPLES = 8
FLOOR = 1e-5
#: Largest spread of the crossing intervals, mismatch of the two frequencies, amplitude drift.
MAX_SPREAD = 0.2
MAX_MISMATCH = 0.03
MAX_DRIFT = 0.1


def upward_crossings(t: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Times at which ``y`` crosses 0 upwards (y[k] < 0 < y[k + 1], or y[k + 1] = 0 < y[k + 2]: a
    touch of zero from below is not a crossing), linear between samples."""
    t, y = np.asarray(t, float), np.asarray(y, float)
    k = np.flatnonzero((y[:-1] < 0.0) & (y[1:] > 0.0) | (y[:-1] < 0.0) & (y[1:] == 0.0)
                       & np.concatenate([y[2:] > 0.0, [False]]))
    return t[k] - y[k] * (t[k + 1] - t[k]) / (y[k + 1] - y[k])


def window_mean(t: np.ndarray, y: np.ndarray, t0: float, t1: float, power: int = 1) -> float:
    """Mean of ``y**power`` over [t0, t1] (trapezoidal, y linear between samples at the ends)."""
    t, y = np.asarray(t, float), np.asarray(y, float) ** power
    inside = (t > t0) & (t < t1)
    tt = np.concatenate([[t0], t[inside], [t1]])
    yy = np.concatenate([[np.interp(t0, t, y)], y[inside], [np.interp(t1, t, y)]])
    return float(np.sum(0.5 * (yy[1:] + yy[:-1]) * np.diff(tt)) / (t1 - t0))


def _extremum(t: np.ndarray, y: np.ndarray, sign: float) -> float:
    """Largest (sign = 1) or smallest (sign = -1) value of ``y``, refined by the vertex of the
    parabola through the extreme sample and its two neighbours (any spacing; the raw sample at an
    end of the period or when the three points are not concave)."""
    k = int(np.argmax(sign * y))
    if k == 0 or k == len(y) - 1:
        return float(y[k])
    (t0, t1, t2), (a, b, c) = t[k - 1:k + 2], sign * y[k - 1:k + 2]
    s1, s2 = (b - a) / (t1 - t0), (c - b) / (t2 - t1)      # divided differences
    curv = (s2 - s1) / (t2 - t0)
    if curv >= 0.0:
        return float(y[k])
    # Newton form p(t) = a + s1 (t - t0) + curv (t - t0)(t - t1): vertex where p' = 0
    tv = 0.5 * (t0 + t1) - 0.5 * s1 / curv
    return float(sign * (a + s1 * (tv - t0) + curv * (tv - t0) * (tv - t1)))


def spectral_frequency(t: np.ndarray, y: np.ndarray) -> float:
    """Frequency of the highest peak of the Hann-windowed periodogram of ``y`` (minus its mean),
    resampled linearly on a uniform grid of as many points, refined by the parabola through the
    logarithms of the peak bin and its two neighbours."""
    t, y = np.asarray(t, float), np.asarray(y, float)
    n = len(t)
    tu = np.linspace(t[0], t[-1], n)
    yu = np.interp(tu, t, y)
    yu = (yu - yu.mean()) * np.hanning(n)
    power = np.abs(np.fft.rfft(yu)) ** 2
    df = 1.0 / (tu[1] - tu[0]) / n
    k = int(np.argmax(power[1:])) + 1
    if k + 1 >= len(power):
        return k * df
    la, lb, lc = (math.log(max(v, 1e-300)) for v in power[k - 1:k + 2])
    den = la - 2.0 * lb + lc
    shift = 0.5 * (la - lc) / den if den < 0.0 else 0.0
    return (k + shift) * df


def whole_period_statistics(t, y, t0: float = 0.0, others: Mapping[str, np.ndarray] | None = None, *,
                            min_periods: int = MIN_PERIODS, min_samples: int = MIN_SAMPLES,
                            floor: float = FLOOR, max_spread: float = MAX_SPREAD,
                            max_mismatch: float = MAX_MISMATCH, max_drift: float = MAX_DRIFT) -> dict:
    """Statistics of the periodic signal ``y(t)`` over its whole periods after ``t0`` (module
    docstring).  Returns ``frequency``, ``frequency_spectral``, ``mean``, ``amplitude``, ``rms``,
    ``n_periods``, ``window`` [t_first, t_last], ``samples_per_period``, ``amplitude_drift`` and
    ``means`` of the ``others`` columns over the same window; or, when the signal does not allow
    them, only ``note`` (why) and the counts that were found."""
    t, y = np.asarray(t, float), np.asarray(y, float)
    after = t >= t0
    if np.count_nonzero(after) < 3:
        return {"note": f"too short: {np.count_nonzero(after)} samples after the transient t = {t0:g} "
                        f"(the run ends at t = {t[-1] if len(t) else float('nan'):g})"}
    ta, ya = t[after], y[after]
    cols = {"y": ya, **{k: np.asarray(v, float)[after] for k, v in (others or {}).items()}}
    for k, v in cols.items():
        if not np.all(np.isfinite(v)):
            return {"note": f"non-finite values of {k} at t = {float(ta[np.argmin(np.isfinite(v))]):g}"}
    # the scale of the flow: the largest |value| of the other columns (the drag), 1 without them
    scale = max((float(np.max(np.abs(v))) for k, v in cols.items() if k != "y"), default=1.0)
    ybar = float(np.mean(ya))
    swing = float(np.max(np.abs(ya - ybar)))
    if swing <= floor * scale:
        return {"note": f"no oscillation: |y - mean| <= {swing:.3g} after t = {t0:g} (below {floor:g} of the "
                        f"signal's scale {scale:.3g}; a mirror-symmetric flow does not shed)"}
    for _ in range(2):   # the mean over whole periods, then the crossings of y minus it
        cross = upward_crossings(ta, ya - ybar)
        if len(cross) < min_periods + 1:
            return {"note": f"too short: {max(len(cross) - 1, 0)} whole period(s) after t = {t0:g}, "
                            f"{min_periods} needed (run longer: larger time.t_end, or a shorter transient)",
                    "n_periods": max(len(cross) - 1, 0)}
        ybar = window_mean(ta, ya, cross[0], cross[-1])
    t_first, t_last = float(cross[0]), float(cross[-1])
    n_per = len(cross) - 1
    period = (t_last - t_first) / n_per
    inside = (ta >= t_first) & (ta <= t_last)
    per_sample = period * np.count_nonzero(inside) / (t_last - t_first)
    if per_sample < min_samples:
        return {"note": f"under-resolved: {per_sample:.3g} samples per period (period {period:.4g}), "
                        f"{min_samples} needed (a shorter output.series_interval, or more output.snapshots)",
                "n_periods": n_per}
    gap = float(np.max(np.diff(np.concatenate([[t_first], ta[inside], [t_last]]))))
    if gap > period / min_samples * 1.5:
        return {"note": f"a gap of {gap:.3g} in the samples (period {period:.4g}): fewer than {min_samples} "
                        "samples per period there", "n_periods": n_per}
    intervals = np.diff(cross)
    spread = float(np.max(np.abs(intervals - np.median(intervals))) / np.median(intervals))
    f_spec = float(spectral_frequency(ta[inside], ya[inside]))
    mismatch = abs(1.0 / period - f_spec)
    if spread > max_spread or mismatch > max(max_mismatch / period, 1.0 / (t_last - t_first)):
        return {"note": f"irregular: crossing intervals spread by {spread:.3g} of their median, zero-crossing "
                        f"frequency {1.0 / period:.4g} against spectral {f_spec:.4g} (another frequency or noise "
                        "in the signal)", "n_periods": n_per}
    amps = []
    for a, b in zip(cross[:-1], cross[1:], strict=True):
        m = (ta >= a) & (ta <= b)
        amps.append(0.5 * (_extremum(ta[m], ya[m], 1.0) - _extremum(ta[m], ya[m], -1.0)))
    drift = float((amps[-1] - amps[0]) / amps[-1])
    if abs(drift) > max_drift:
        return {"note": f"not saturated: the amplitude changes by {drift:+.3g} from the first to the last whole "
                        f"period after t = {t0:g} (a growing or decaying oscillation; a longer transient, or no "
                        "shedding)", "n_periods": n_per, "amplitude_drift": drift}
    out = {"frequency": 1.0 / period, "frequency_spectral": f_spec,
           "mean": ybar, "amplitude": float(np.mean(amps)),
           "rms": math.sqrt(window_mean(ta, ya - ybar, t_first, t_last, power=2)),
           "n_periods": n_per, "window": [t_first, t_last], "samples_per_period": float(per_sample),
           "amplitude_drift": drift}
    if others:
        out["means"] = {k: window_mean(t, np.asarray(v, float), t_first, t_last) for k, v in others.items()}
    return out
