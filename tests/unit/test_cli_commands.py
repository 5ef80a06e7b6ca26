"""The ``umay`` parser is put together from the commands each folder registers
(deploy/cli.py): every command is there once, in the help's order, each with its handler."""

from __future__ import annotations

import argparse

import pytest

from deploy.cli import HELP_ORDER, build_parser, commands, main
from deploy.exit_codes import EXIT_BAD_INPUT


def _subcommands(parser: argparse.ArgumentParser) -> argparse._SubParsersAction:
    (action,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return action


def test_every_registered_command_is_listed_in_the_help_order() -> None:
    assert sorted(commands()) == sorted(HELP_ORDER)
    assert list(_subcommands(build_parser()).choices) == list(HELP_ORDER)


def test_every_command_has_a_handler() -> None:
    for name, sub in _subcommands(build_parser()).choices.items():
        assert callable(sub.get_default("func")), name


def test_an_option_of_a_folder_command_is_parsed_by_the_top_parser() -> None:
    args = build_parser().parse_args(["status", "--timeout", "2.5", "--json"])
    assert (args.command, args.timeout, args.json) == ("status", 2.5, True)
    with pytest.raises(SystemExit):  # positive_seconds refuses 0, as before the split
        build_parser().parse_args(["record", "out.mcap", "--duration", "0"])


def test_a_handler_error_becomes_the_exit_code(tmp_path, capsys) -> None:
    assert main(["info", str(tmp_path / "missing.mcap")]) == EXIT_BAD_INPUT
    assert "no such file" in capsys.readouterr().err
