"""Paired comparisons with 95 % confidence intervals, and the verdicts that follow from them.

A comparison of two methods pairs the runs that share everything but the method (the same
initialization seed, split and data): for each pair the ratio r_i = MSE_baseline,i / MSE_method,i.
The ratio's geometric mean and its Student-t interval are computed on log r_i, so a ratio of 2 and
one of 1/2 weigh the same. "helps" needs the whole interval above 1, "hurts" the whole interval
below 1; anything else is "no clear difference" (too few pairs, or a real tie).
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

CONFIDENCE = 0.95


def ratio_interval_text(ratio: float, low: float, high: float) -> str:
    """'3.1x [2.2, 4.4]': 3 significant digits, more (up to 6) where 3 would print a number that is not 1 as 1
    ("1x [1, 1]" for 1.004x [1.001, 1.008], an interval that excludes 1) or an interval's two ends alike."""
    digits = 3
    while digits < 6:
        shown = [f"{value:.{digits}g}" for value in (ratio, low, high)]
        hides_one = any(text == "1" and value != 1.0 for text, value in zip(shown, (ratio, low, high)))
        if not hides_one and (shown[1] != shown[2] or low == high):
            break
        digits += 1
    return f"{ratio:.{digits}g}x [{low:.{digits}g}, {high:.{digits}g}]"


@dataclasses.dataclass(frozen=True)
class PairedRatio:
    """Geometric-mean ratio baseline/method over n pairs and its 95 % interval (low, high)."""
    ratio: float
    low: float
    high: float
    pairs: int

    @property
    def verdict(self) -> str:
        if self.pairs >= 2 and self.low > 1.0:
            return "helps"
        if self.pairs >= 2 and self.high < 1.0:
            return "hurts"
        return "no clear difference"

    def text(self) -> str:
        """e.g. '3.1x [2.2, 4.4]' (ratio > 1: the method's MSE is lower)."""
        if self.pairs < 2:
            return f"{self.ratio:.3g}x (1 pair, no interval)"
        return ratio_interval_text(self.ratio, self.low, self.high)

    def as_dict(self) -> dict:
        return dict(ratio=self.ratio, low=self.low, high=self.high, pairs=self.pairs, verdict=self.verdict)


def paired_ratio(baseline, method) -> PairedRatio:
    """Paired ratios baseline_i / method_i (positive values, same order): geometric mean and the 95 %
    Student-t interval of the mean log ratio, exponentiated. One pair gives an infinite interval."""
    from scipy import stats

    baseline, method = np.asarray(baseline, dtype=float), np.asarray(method, dtype=float)
    if baseline.shape != method.shape or baseline.ndim != 1 or len(baseline) == 0:
        raise ValueError(f"paired_ratio needs two equal-length 1-D sequences, got {baseline.shape} and {method.shape}")
    if not (np.all(baseline > 0) and np.all(method > 0)):
        raise ValueError("paired_ratio needs positive values")
    logs = np.log(baseline) - np.log(method)
    mean = float(logs.mean())
    if len(logs) < 2:
        return PairedRatio(math.exp(mean), 0.0, math.inf, len(logs))
    half = float(stats.t.ppf(0.5 + CONFIDENCE / 2, len(logs) - 1) * logs.std(ddof=1) / math.sqrt(len(logs)))
    return PairedRatio(math.exp(mean), math.exp(mean - half), math.exp(mean + half), len(logs))
