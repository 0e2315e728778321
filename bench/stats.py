"""What every latency benchmark reports of its samples, and the one histogram/box-plot helper they share."""

from __future__ import annotations

import statistics
from pathlib import Path


def latency_summary(values_ns: list[int]) -> dict[str, float]:
    """Mean, standard deviation, median, p99, min and max of ``values_ns``, in microseconds."""
    us = sorted(v / 1000 for v in values_ns)
    return {
        "mean": statistics.fmean(us),
        "sd": statistics.stdev(us) if len(us) > 1 else 0.0,
        "median": statistics.median(us),
        "p99": us[min(len(us) - 1, int(len(us) * 0.99))],
        "min": us[0],
        "max": us[-1],
    }


def microseconds(values_ns: list[int]) -> list[float]:
    return [v / 1000 for v in values_ns]


def histogram(series: dict[str, list[int]], path: Path, title: str, bins: int = 60) -> None:
    """One overlaid histogram of latency samples (ns) per label, as the IXM paper's Fig. 9."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    every = [v for values in series.values() for v in microseconds(values)]
    if not every:
        plt.close(fig)
        return
    top = sorted(every)[min(len(every) - 1, int(len(every) * 0.995))]
    for label, values in series.items():
        ax.hist([min(v, top) for v in microseconds(values)], bins=bins, range=(0, top), alpha=0.5, label=label)
    ax.set_xlabel("latency (µs; the last bin holds everything beyond p99.5)")
    ax.set_ylabel("occurrences")
    ax.set_title(title)
    ax.legend(fontsize="small")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
