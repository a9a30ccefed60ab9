"""The CLI reference page, generated from the `cnep` parsers.

`python -m cnep.pipeline.cli.reference docs/reference/cli.md` writes it (`make docs`; without a path: to
stdout). tests/test_docs.py fails when the committed page differs from `render()`, so a flag added without
regenerating is caught.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from cnep.pipeline.cli.main import build_parser

HEADER = """\
# CLI reference

Every `cnep` subcommand and its options, generated from the command's own parsers (`make docs`
regenerates this page; do not edit it by hand). Exit status, error lines and the rules for outputs
are the same for every subcommand: [the CLI contract](cli-contract.md). `cnep COMMAND --help` prints
the same text.
"""
# argparse's own groups (its name for options changed in Python 3.10): listed in one table, without a title.
UNTITLED = ("positional arguments", "options", "optional arguments")


def render(parser: argparse.ArgumentParser | None = None) -> str:
    """The whole page (Markdown) for `parser` (default: the `cnep` parser)."""
    parser = parser or build_parser()
    commands = _subcommands(parser)
    lines = [HEADER, "## Global options", "", "Given before the subcommand: `cnep -q train ...`.", ""]
    lines += _table(parser, [a for a in parser._actions if a.option_strings and not _is_help(a)])
    for name, sub in commands.items():
        lines += ["", f"## `cnep {name}`", "", _sentence(sub.description), "", f"`{_synopsis(name, sub)}`", ""]
        untitled = [g for g in sub._action_groups if g.title in UNTITLED]  # positionals first, then options
        lines += _table(sub, [a for g in untitled for a in g._group_actions if not _is_help(a)]) + [""]
        for group in sub._action_groups:
            if group.title not in UNTITLED and group._group_actions:
                lines += [f"**{_sentence(group.title)}**", "", *_table(sub, group._group_actions), ""]
        while lines[-1] == "":
            lines.pop()
    return "\n".join(lines) + "\n"


def _subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    """Name -> parser of every subcommand; one with subcommands of its own (`sim`) is listed as theirs (`sim eval`)."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            found = {}
            for name, sub in action.choices.items():
                nested = _subcommands(sub)
                found.update({f"{name} {n}": p for n, p in nested.items()} if nested else {name: sub})
            return found
    return {}


def _is_help(action: argparse.Action) -> bool:
    return isinstance(action, (argparse._HelpAction, argparse._VersionAction)) and action.dest != "version"


def _table(parser: argparse.ArgumentParser, actions: list[argparse.Action]) -> list[str]:
    formatter = parser._get_formatter()
    rows = ["| argument | meaning |", "|---|---|"]
    for action in actions:
        invocation = formatter._format_action_invocation(action)
        required = " (required)" if action.option_strings and action.required else ""
        meaning = formatter._expand_help(action) if action.help else ""
        rows.append(f"| `{_cell(invocation)}`{required} | {_cell(meaning)} |")
    return rows


def _synopsis(name: str, parser: argparse.ArgumentParser) -> str:
    words = [f"cnep {name}"]
    for action in parser._actions:
        if action.option_strings and action.required:
            words.append(f"{action.option_strings[-1]} {action.metavar or action.dest.upper()}")
    words.append("[options]")
    for action in parser._actions:
        if not action.option_strings:
            metavar = action.metavar or action.dest
            words.append(f"{metavar}..." if action.nargs in ("+", "*") else metavar)
    return " ".join(words)


def _sentence(text: str | None) -> str:
    text = (text or "").strip()
    return text[:1].upper() + text[1:] + ("" if text.endswith(".") or not text else ".")


def _cell(text: str) -> str:
    """Text safe inside a Markdown table cell: one line, `|` escaped."""
    return " ".join(text.split()).replace("|", "\\|")


def main(argv: list[str]) -> None:
    """Write the page to the path in `argv` (whole or not at all), or to stdout without one."""
    if not argv:
        sys.stdout.write(render())
        return
    from cnep.outputs import write_atomically

    write_atomically(Path(argv[0]), render().encode())


if __name__ == "__main__":
    main(sys.argv[1:])
