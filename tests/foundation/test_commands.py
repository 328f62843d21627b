"""The command tables (services/commands.toml): `mimic X --help` and `mimic bench X --help` work for every entry."""

from __future__ import annotations

import pytest

from services.cli import main as mimic
from services.commands import command_table

CASES = [([name], help_text) for name, (_, help_text) in command_table("mimic").items()] + [
    (["bench", name], help_text) for name, (_, help_text) in command_table("bench").items()
]


@pytest.mark.parametrize(("argv", "help_text"), CASES, ids=[" ".join(a) for a, _ in CASES])
def test_every_command_prints_its_help(argv, help_text, capsys):
    with pytest.raises(SystemExit) as exc:
        mimic([*argv, "--help"])
    assert exc.value.code == 0
    out = " ".join(capsys.readouterr().out.split())
    assert out.startswith(f"usage: mimic {' '.join(argv)}")
    assert " ".join(help_text.split()) in out


def test_top_level_help_lists_every_command(capsys):
    assert mimic([]) == 2
    out = capsys.readouterr().out
    for name in command_table("mimic"):
        assert f"\n    {name} " in out
