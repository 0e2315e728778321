"""What every latency benchmark reports of its samples."""

from __future__ import annotations

import statistics


def latency_summary(values_ns: list[int]) -> dict[str, float]:
    """Mean, median, p99 and max of ``values_ns``, in microseconds."""
    us = sorted(v / 1000 for v in values_ns)
    return {
        "mean": statistics.fmean(us),
        "median": statistics.median(us),
        "p99": us[min(len(us) - 1, int(len(us) * 0.99))],
        "max": us[-1],
    }
