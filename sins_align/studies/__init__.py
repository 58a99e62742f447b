"""Comparison studies (issue 13): the seeds' published methods beside ours on the same
simulated data. ``python -m sins_align.montecarlo --study NAME --runs N --json OUT --plot OUT.png``
runs one.

:data:`STUDIES` maps each name to its ``run(runs=..., seed=..., duration=None) -> dict``
(JSON-ready: per case and filter ``final_error_deg`` {``mean``, ``rmse``} on E/N/U,
``time_to_level_s``, ``time_to_heading_s``, ``cpu_s``); :func:`summary_text` and
:func:`write_plot` render any study's result.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

from sins_align.studies import feedback, seed003, seed004

_MODULES = {"seed004": seed004, "seed003": seed003, "feedback": feedback}
STUDIES: dict[str, Callable[..., dict[str, Any]]] = {k: m.run for k, m in _MODULES.items()}

__all__ = ["STUDIES", "summary_text", "write_plot"]


def summary_text(result: dict[str, Any]) -> str:
    """One screen of a study's result."""
    return _MODULES[result["study"]].summary_text(result)


def write_plot(path: Path | str, result: dict[str, Any]) -> None:
    """A study's figure (PNG, needs matplotlib)."""
    _MODULES[result["study"]].write_plot(path, result)
