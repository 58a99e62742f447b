"""The replay commands the READMEs show start: since session 18 replay refuses to run
without a grade (or the four specs), so a command copied from a README without one stops at
"grade is required" (bags/README.md's three did)."""
from __future__ import annotations

import shlex
from pathlib import Path

import pytest

from sins_align.tools import replay

ROOT = Path(__file__).resolve().parents[1]
READMES = ("README.md", "bags/README.md")
STARTS = ("python -m sins_align.replay ", "ros2 run sins_align replay ")


def _commands(text: str) -> list[list[str]]:
    """The replay commands' arguments: lines starting (after indentation or a '$ ' prompt)
    with one of STARTS, with their '\\' continuation lines."""
    out, lines, i = [], text.splitlines(), 0
    while i < len(lines):
        line = lines[i].strip().removeprefix("$ ")
        start = next((s for s in STARTS if line.startswith(s)), None)
        i += 1
        if start is None:
            continue
        cmd = line[len(start):]
        while cmd.endswith("\\") and i < len(lines):
            cmd = cmd[:-1] + " " + lines[i].strip()
            i += 1
        cmd = cmd.replace("$(ros2 pkg prefix sins_align)", "/opt/prefix")
        out.append(shlex.split(cmd, comments=True))
    return out


def _checked(argv: list[str]):
    args = replay.build_parser().parse_args(argv)
    values, _ = replay.params_from_args(args)
    return replay.config_or_error(values)


@pytest.mark.parametrize("readme", READMES)
def test_the_readmes_replay_commands_are_configured(readme, monkeypatch):
    """Each command's flags (and its parameters file, where the repository has it; a file
    a README writes first, /tmp/..., is left out) make a configuration; none is refused."""
    monkeypatch.chdir(ROOT)
    cmds = _commands((ROOT / readme).read_text())
    checked = 0
    for argv in cmds:
        args = replay.build_parser().parse_args(argv)
        if args.params and not (ROOT / args.params).is_file():
            continue
        try:
            _checked(argv)
        except replay.CliError as e:
            raise AssertionError(f"{readme}: replay {shlex.join(argv)}: {e}") from None
        checked += 1
    assert checked >= 3, (readme, cmds)


def test_a_command_without_a_grade_is_refused():
    """(The check above can fail: the same flags without --grade are refused.)"""
    with pytest.raises(replay.CliError, match="grade is required"):
        _checked(["bags/lasergyro_300s", "--latitude", "34.246048"])
