"""Benchmark figures with the independent trials behind them: success rates with a 95 % Wilson interval, means with a 95 % t interval."""

from __future__ import annotations

import math
from collections.abc import Sequence

Z95 = 1.959963984540054  # the standard normal's 97.5 % quantile


def wilson(k: int, n: int, z: float = Z95) -> tuple[float, float]:
    """The Wilson score interval of ``k`` successes in ``n`` independent trials (0 and 1 included; (0, 1) for n=0).

    Unlike the normal approximation it stays inside [0, 1] and is not empty at 0/n or n/n,
    the figures small benchmarks produce.
    """
    if not 0 <= k <= n:
        raise ValueError(f"wilson: {k} successes in {n} trials")
    if n == 0:
        return 0.0, 1.0
    p = k / n
    z2 = z * z
    centre = (p + z2 / (2 * n)) / (1 + z2 / n)
    half = z * math.sqrt(p * (1 - p) / n + z2 / (4 * n * n)) / (1 + z2 / n)
    # exactly 0 and 1 at 0/n and n/n, where the arithmetic leaves a rounding error
    return (0.0 if k == 0 else centre - half), (1.0 if k == n else centre + half)


def rate(k: int, n: int) -> dict:
    """A success rate for a benchmark's JSON: successes, trials, rate and its 95 % interval."""
    lo, hi = wilson(k, n)
    return {"successes": k, "trials": n, "rate": k / n if n else 0.0, "ci95": [lo, hi]}


def rate_text(k: int, n: int) -> str:
    """``27/30 = 90 % [74-97 %]``: the count, the rate and its 95 % Wilson interval, for a table cell."""
    lo, hi = wilson(k, n)
    return f"{k}/{n} = {100 * k / n:.0f} % [{100 * lo:.0f}-{100 * hi:.0f} %]" if n else "0/0"


def mean_interval(values: Sequence[float], level: float = 0.95) -> tuple[float, float] | None:
    """The Student t interval of the mean of ``values`` (independent runs); None for fewer than two.

    A figure per run (attempts per box, time per box) is chaotic in its seed: the same seed
    gave 8 and 23 attempts on two machines. So a mean over ten runs says little without
    this interval, and a goal inside it is neither met nor missed. The t interval assumes
    roughly normal means; a skewed figure (one box of 53 attempts among boxes of 8-22) makes
    it approximate.
    """
    from scipy.stats import t as student

    if not 0.0 < level < 1.0:
        raise ValueError(f"mean_interval: level {level!r} is not in (0, 1)")
    n = len(values)
    if n < 2:
        return None
    mean = math.fsum(values) / n
    sd = math.sqrt(math.fsum((v - mean) ** 2 for v in values) / (n - 1))
    half = float(student.ppf(0.5 + level / 2, n - 1)) * sd / math.sqrt(n)
    return mean - half, mean + half


def mean(values: Sequence[float]) -> dict:
    """A mean for a benchmark's JSON: the mean, the runs behind it and its 95 % interval (None under two runs)."""
    ci = mean_interval(values)
    return {"mean": math.fsum(values) / len(values) if values else 0.0, "runs": len(values),
            "ci95": list(ci) if ci is not None else None}


def mean_text(value: float, ci: Sequence[float] | None, digits: int = 1) -> str:
    """``16.9 [7.3-26.5]``: a mean and its 95 % interval (``mean``'s ``ci95``), for a table cell; the mean alone
    without an interval (one run)."""
    return f"{value:.{digits}f}" if ci is None else f"{value:.{digits}f} [{ci[0]:.{digits}f}-{ci[1]:.{digits}f}]"
