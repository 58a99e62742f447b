"""What the studies share: settling times, medians over runs, the error-grid plot."""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Callable

import numpy as np

__all__ = ["settle_time", "median_or_none", "error_grid", "check_names"]


def check_names(study: str, what: str, given, allowed) -> None:
    """ValueError naming the first of ``given`` that is not one of ``allowed``."""
    for x in given:
        if x not in allowed:
            raise ValueError(f"{study}: unknown {what} {x!r}; choose from {tuple(allowed)}")


def settle_time(ok: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Per run: first time after which ``ok`` (T, n) stays true to the end (inf = never)."""
    bad = ~ok
    last_bad = np.where(bad.any(axis=0), len(ok) - 1 - np.argmax(bad[::-1], axis=0), -1)
    return np.append(times, np.inf)[last_bad + 1]


def median_or_none(st: np.ndarray):
    """Median over the runs; None when it is infinite (half of the runs or more never)."""
    m = float(np.median(st)) if len(st) else math.inf
    return m if math.isfinite(m) else None


def error_grid(path, res: dict[str, Any], series: str, titles: tuple[str, str, str],
               ylabel: str, suptitle: str,
               reference: Callable[[dict, int], tuple[float, dict] | None] | None = None):
    """RMS error against time on a log scale, one row per case and one column per axis:
    ``res["cases"][case]["filters"][name]["series"]`` holds ``time_s`` and ``series``
    (T, 3; None where no run has a value); ``reference(case result, axis)`` may give a
    horizontal line (value, matplotlib keywords)."""
    from sins_align.io.bagio import pyplot

    plt = pyplot()
    cases = list(res["cases"])
    fig, axes = plt.subplots(len(cases), 3, figsize=(13, 3.2 * len(cases)), squeeze=False,
                             sharex=True)
    for i, case in enumerate(cases):
        c = res["cases"][case]
        for j, ax in enumerate(axes[i]):
            for k, (f, r) in enumerate(c["filters"].items()):
                tt = np.array(r["series"]["time_s"], float)
                y = np.array([np.nan if v is None else v
                              for v in np.array(r["series"][series], object)[:, j]], float)
                ax.semilogy(tt, y, color=f"C{k}", lw=1.2, label=f)
            line = reference(c, j) if reference is not None else None
            if line is not None:
                ax.axhline(line[0], **line[1])
            ax.set_title(f"{case}: {titles[j]}", fontsize="medium")
            ax.grid(True, alpha=0.3)
            if j == 0:
                ax.set_ylabel(ylabel)
    axes[0][0].legend(fontsize="small")
    for ax in axes[-1]:
        ax.set_xlabel("time, s")
    fig.suptitle(suptitle, fontsize="medium")
    fig.tight_layout()
    fig.savefig(Path(path), format="png", dpi=90)
    plt.close(fig)
