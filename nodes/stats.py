"""Success rates as benchmarks report them: the count, the independent trials behind it, and a 95 % Wilson interval."""

from __future__ import annotations

import math

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
