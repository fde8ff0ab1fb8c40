"""A twin's history: every record's assessment in time order, and its trend figure with control limits.

``trend.tsv`` holds one row per record and parameter entry (``TREND_COLUMNS``): the record's time stamp, verdict,
chi^2/dof and p-value, then the parameter's twin value and the record's estimate with its interval (its
``Assessment.parameters`` row). ``add`` puts a record in (replacing an earlier assessment of the same record) by
writing a new file next to the old one and renaming it over it: a failed or interrupted assessment never leaves a
half-written trend. ``read_trend`` is the exact inverse of the writer.

The figure (``plot_trend``): chi^2/dof per record against its alarm limit chi^2_{1-alpha}(dof) / dof, and each
parameter's estimate with its 95 % interval against the twin's value; the control limits drawn per record are
twin -+ z_{1-alpha/2} sqrt(twin_stderr^2 + stderr^2), where the record's estimate alone would differ from the twin
at level alpha. Records whose verdict is not "consistent" are drawn red (changed) or black (new discrepancy).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.special import chdtri, ndtri  # chi^2's inverse survival function, the normal quantile

from .. import tables
from .assess import Assessment, RecordVerdict

#: the trend's columns: the record's, then its parameter rows' (the parameter test's dof and p-value renamed)
RECORD_COLUMNS = list(tables.TREND_RECORD_COLUMNS)
ENTRY_COLUMNS = list(tables.TREND_ENTRY_COLUMNS)
TREND_COLUMNS = RECORD_COLUMNS + ENTRY_COLUMNS
COLOURS = {RecordVerdict.CONSISTENT.value: "tab:blue", RecordVerdict.CHANGED.value: "tab:red",
           RecordVerdict.NEW_DISCREPANCY.value: "k"}


def rows(assessment: Assessment) -> pd.DataFrame:
    """The record's rows of the trend."""
    table = assessment.parameters.rename(columns={"dof": "test_dof", "p_value": "test_p_value"})
    out = table[ENTRY_COLUMNS].copy()
    for column in reversed(RECORD_COLUMNS):
        out.insert(0, column, assessment.summary[column])
    return out


def add(path: str | Path, assessment: Assessment) -> pd.DataFrame:
    """The trend at ``path`` with ``assessment`` in it (an earlier one of the same record replaced), written
    atomically (module docstring); returns it."""
    path = Path(path)
    old = read_trend(path) if path.is_file() else pd.DataFrame(columns=TREND_COLUMNS)
    old = old[old["record"] != assessment.summary["record"]]
    return write_trend(pd.concat([old, rows(assessment)], ignore_index=True) if len(old) else rows(assessment), path)


def write_trend(trend: pd.DataFrame, path: str | Path) -> pd.DataFrame:
    """Write ``trend`` sorted by time stamp (then record) by way of a temporary file renamed over ``path``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    trend = trend.sort_values(["timestamp", "record"], kind="stable").reset_index(drop=True)[TREND_COLUMNS]
    temporary = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        tables.TREND.write(trend, temporary)
        os.replace(temporary, path)
    finally:
        temporary.unlink(missing_ok=True)
    return trend


def read_trend(path: str | Path) -> pd.DataFrame:
    """trend.tsv as written: text columns as text, ``moved`` as bool, the others as numbers."""
    table = tables.TREND.read(path)
    missing = [c for c in TREND_COLUMNS if c not in table]
    if missing:
        raise ValueError(f"{path}: not a trend file (no column(s) {missing})")
    return table[TREND_COLUMNS]


def plot_trend(trend: pd.DataFrame, twin: str = ""):
    """The trend figure (module docstring): chi^2/dof, then one panel per parameter the twin determined (per-run
    parameters from steady records only: a run-up's bow is one value per band)."""
    import matplotlib.pyplot as plt  # here, not at import (the command's verdict needs no matplotlib); no backend
    # forced: Agg by itself without a display, or the caller's choice

    records = trend.drop_duplicates("record")
    if records.empty:
        fig, ax = plt.subplots(figsize=(9, 2))
        ax.set_title(f"twin {twin}: no record assessed yet", fontsize=9)
        ax.axis("off")
        return fig
    when = pd.to_datetime(records["timestamp"], utc=True, format="ISO8601")
    entries = trend[(trend["run"] == "all") | (trend["run"] == trend["record"])]
    entries = entries[entries["twin_stderr"].notna()]  # a parameter the twin left undetermined has no limits
    names = list(dict.fromkeys(entries["parameter"]))
    fig, axes = plt.subplots(len(names) + 1, 1, figsize=(9, 1.9 * (len(names) + 1) + 0.6), sharex=True,
                             squeeze=False)
    axes = axes[:, 0]
    limit = chdtri(records["dof"].to_numpy(float), records["alpha"].to_numpy(float)) / records["dof"]
    axes[0].plot(when, limit, drawstyle="steps-mid", color="0.5", lw=1, label=r"alarm limit $\chi^2_{1-\alpha}$/dof")
    axes[0].scatter(when, records["chi2_dof"], c=[COLOURS[v] for v in records["verdict"]], zorder=3, s=18)
    axes[0].set_yscale("log")
    axes[0].set_ylabel(r"$\chi^2$/dof at the twin")
    axes[0].legend(loc="upper left", fontsize=7)
    axes[0].set_title(f"twin {twin}: {len(records)} record(s); blue consistent, red changed, black new discrepancy",
                      fontsize=9)
    for ax, name in zip(axes[1:], names):
        rows_ = entries[entries["parameter"] == name]
        t = pd.to_datetime(rows_["timestamp"], utc=True, format="ISO8601")
        z = -ndtri(rows_["alpha"].to_numpy(float) / 2)
        half = z * np.hypot(rows_["twin_stderr"].fillna(0), rows_["stderr"].fillna(0))
        ax.plot(t, rows_["twin_value"], color="0.3", lw=1, label="twin")
        ax.plot(t, rows_["twin_value"] - half, color="0.6", lw=0.8, ls="--", drawstyle="steps-mid",
                label="control limits")
        ax.plot(t, rows_["twin_value"] + half, color="0.6", lw=0.8, ls="--", drawstyle="steps-mid")
        colours = [COLOURS[v] for v in rows_["verdict"]]
        ax.errorbar(t, rows_["value"], yerr=rows_["value"] - rows_["ci_low"], fmt="none", ecolor="0.7", lw=0.8)
        ax.scatter(t, rows_["value"], c=colours, s=14, zorder=3)
        unit = rows_["unit"].iloc[0]
        ax.set_ylabel(f"{name} [{unit}]" if unit not in ("", "1") else name, fontsize=8)
    axes[1 if len(axes) > 1 else 0].legend(loc="upper left", fontsize=7)
    axes[-1].set_xlabel("record time stamp")
    fig.autofmt_xdate()
    height = fig.get_figheight()  # margins in inches, fixed: tight_layout measured every label (~1 s of a 2-s figure)
    fig.subplots_adjust(left=0.12, right=0.98, top=1 - 0.35 / height, bottom=0.75 / height, hspace=0.12)
    return fig
