"""Axis formatting the figures share."""

from __future__ import annotations

from matplotlib.axis import Axis
from matplotlib.ticker import LogFormatter


class _PlainLog(LogFormatter):
    """matplotlib's choice of which log ticks to label, each written as a plain number."""

    def _num_to_string(self, x: float, vmin: float, vmax: float) -> str:
        return f"{x:g}"


def plain_log_labels(axis: Axis) -> None:
    """A log axis labelled 0.1, 2, 30, 400 rather than 10^-1, 2x10^0, 3x10^1, 4x10^2 (the
    same ticks matplotlib picks; minor ones labelled over up to 2.5 decades)."""
    axis.set_major_formatter(_PlainLog())
    axis.set_minor_formatter(_PlainLog(labelOnlyBase=False, minor_thresholds=(2.5, 0.5)))
