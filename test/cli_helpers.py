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


def simulated_bags(tmp_path: Path, seconds: int = 40):
    """``simulate``'s static 100 Hz bags of ``seconds`` s (latitude 34) with zstd chunks and
    uncompressed: yields (compression, bag directory)."""
    from sins_align.tools import simulate

    for comp in ("zstd", "none"):
        bag = tmp_path / f"sim_{comp}"
        assert simulate.main(["--latitude", "34", "--duration", str(seconds), "--rate", "100",
                              "--compression", comp, str(bag)]) == 0
        yield comp, bag
