"""Helpers shared by the command-line tool tests (test_bag_tools, test_cli_surprises)."""
from __future__ import annotations

from pathlib import Path


def cli(mod, args, capsys):
    """Run a tool's main() in-process: (exit code, stdout, stderr)."""
    rc = mod.main([str(a) for a in args])
    out, err = capsys.readouterr()
    return rc, out, err


def listing(d: Path) -> set[str]:
    """Every entry under ``d`` (hidden ones included), relative to it."""
    return {str(p.relative_to(d)) for p in d.rglob("*")}
