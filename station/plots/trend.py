"""A PNG of measurements across records: each measurement against its limits, run after run.

What a line engineer looks at first: which quantity drifts towards its limit, which units failed.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Protocol

import numpy as np

from station.common.files import atomic_open


class Measured(Protocol):
    """One measurement of a run record, as the plot reads it (``station.factory.records.Measurement``)."""

    @property
    def name(self) -> str:
        """The measurement's name (``gyro.bias.x``)."""

    @property
    def value(self) -> object:
        """Its value: a number where it can be plotted."""

    @property
    def unit(self) -> str:
        """The unit of value and limits."""

    @property
    def low(self) -> float | None:
        """The lower limit, if any."""

    @property
    def high(self) -> float | None:
        """The upper limit, if any."""

    @property
    def outcome(self) -> str:
        """PASS, FAIL, ..."""


class RunRecord(Protocol):
    """A run record, as the plot reads it (``station.factory.records.RunRecord``): the plots are drawn
    below the factory, which stores the records."""

    @property
    def serial(self) -> str:
        """The unit's serial."""

    def measurements(self) -> Mapping[str, Measured]:
        """Its measurements by name."""

MAX_PANELS = 12


def trend_series(records: Sequence[RunRecord], names: list[str] | None = None) -> dict[str, dict]:
    """Per measurement name: values (NaN where a record lacks it), unit, limits and outcomes, in record order.

    Without ``names``: every numeric measurement that has limits in at least one record.
    """
    if names is None:
        names = []
        for r in records:
            for measured in r.measurements().values():
                limited = measured.low is not None or measured.high is not None
                if limited and isinstance(measured.value, int | float) and measured.name not in names:
                    names.append(measured.name)
    series = {}
    for name in names:
        values, outcomes, unit, low, high = [], [], "", None, None
        for r in records:
            m = r.measurements().get(name)
            values.append(float(m.value) if m is not None and isinstance(m.value, int | float) else np.nan)
            outcomes.append(m.outcome if m is not None else "")
            if m is not None:
                unit, low, high = m.unit, m.low, m.high
        series[name] = {"values": np.array(values), "outcomes": outcomes, "unit": unit, "low": low,
                        "high": high}
    return series


def left_out(records: Sequence[RunRecord], names: list[str] | None = None) -> dict[str, str]:
    """The measurements :func:`write_trend_plot` leaves out of the PNG, each with why.

    Parameters
    ----------
    records : list of RunRecord
        The records plotted.
    names : list of str, optional
        The measurements asked for (``--measurement``); None: every one with limits.

    Returns
    -------
    dict of str to str
        Measurement name to the reason: not a number, no limits, in no record, or beyond the
        :data:`MAX_PANELS` panels.
    """
    seen: dict[str, list] = {}
    for r in records:
        for m in r.measurements().values():
            seen.setdefault(m.name, []).append(m)
    out = {}
    for name in (list(seen) if names is None else names):
        found = seen.get(name, [])
        numeric = [m for m in found if isinstance(m.value, int | float) and not isinstance(m.value, bool)]
        if not found:
            out[name] = "in no record"
        elif not numeric:
            out[name] = "not a number"
        elif names is None and not any(m.low is not None or m.high is not None for m in numeric):
            out[name] = "no limits"
    for name in list(trend_series(records, names))[MAX_PANELS:]:
        out[name] = f"beyond the {MAX_PANELS} panels"
    return out


def write_trend_plot(path: str | Path, records: Sequence[RunRecord],
                     names: list[str] | None = None) -> list[str]:
    """Write the PNG; returns the measurement names plotted (at most :data:`MAX_PANELS`)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    series = dict(list(trend_series(records, names).items())[:MAX_PANELS])
    n = max(1, len(series))
    cols = 2 if n > 1 else 1
    rows = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(6 * cols, 2.2 * rows + 0.6), squeeze=False)
    x = np.arange(len(records))
    labels = [r.serial for r in records]
    for ax, (name, s) in zip(axes.ravel(), series.items(), strict=False):
        failed = np.array([o == "FAIL" for o in s["outcomes"]])
        ax.plot(x, s["values"], "-", color="0.7", lw=0.8)
        ax.plot(x[~failed], s["values"][~failed], "o", color="tab:blue", ms=4, label="pass")
        if failed.any():
            ax.plot(x[failed], s["values"][failed], "x", color="tab:red", ms=7, mew=2, label="fail")
        for bound in (s["low"], s["high"]):
            if bound is not None:
                ax.axhline(bound, color="tab:red", ls="--", lw=1)
        ax.set_title(name + (f" ({s['unit']})" if s["unit"] else ""), fontsize=9)
        ax.set_xticks(x, labels if len(records) <= 20 else [""] * len(records), rotation=60, fontsize=6)
    for ax in axes.ravel()[len(series):]:
        ax.set_visible(False)
    fig.suptitle(f"imu-station records: {len(records)} run(s), limits dashed, failures x", fontsize=10)
    fig.tight_layout()
    with atomic_open(path, "wb") as fh:
        fig.savefig(fh, format="png", dpi=100)
    plt.close(fig)
    return list(series)
