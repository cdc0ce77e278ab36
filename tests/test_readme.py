"""The README's synopsis lists every flag that its own examples use, and only flags that exist."""

from __future__ import annotations

import argparse
import re
from pathlib import Path

from service.cli.main import build_parser

README = Path(__file__).resolve().parents[1] / "README.md"
FLAG = re.compile(r"(?<![\w-])(--[a-z][a-z0-9-]*|-o)\b")


def _synopsis(text: str) -> dict[str, set[str]]:
    """Command -> flags of the synopsis block (the first code block after '## Command line')."""
    block = text.split("## Command line", 1)[1].split("```", 2)[1]
    out: dict[str, set[str]] = {}
    command = ""
    for line in block.splitlines():
        m = re.match(r"recal (\w+|-)", line)
        if m:
            command = "" if m.group(1) == "-" else m.group(1)
        out.setdefault(command, set()).update(FLAG.findall(line))
    return out


def _examples(text: str) -> list[tuple[str, set[str]]]:
    """(command, flags) of every `recal <command>` invocation in the README's bash blocks."""
    calls = []
    for block in re.findall(r"```bash\n(.*?)```", text, re.DOTALL):
        for line in block.replace("\\\n", " ").splitlines():
            for part in re.split(r"&&|\|\||;|\|", line.split("#", 1)[0]):
                m = re.search(r"\brecal (\w+)(.*)", part)
                if m:
                    calls.append((m.group(1), set(FLAG.findall(m.group(2)))))
    return calls


def test_the_synopsis_lists_every_flag_the_examples_use() -> None:
    text = README.read_text()
    synopsis = _synopsis(text)
    synopsis["diagnose"] |= synopsis["calibrate"] - {
        "-o"
    }  # "[calibrate's options, no output file]"
    calls = _examples(text)
    assert len(calls) > 10
    missing = sorted(
        {(cmd, f) for cmd, flags in calls for f in flags - synopsis.get(cmd, set()) - {"--help"}}
    )
    assert not missing, missing


def test_every_synopsis_flag_exists() -> None:
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    for command, flags in _synopsis(README.read_text()).items():
        if command not in sub.choices:
            continue
        parsers, known = [sub.choices[command]], set()
        for parser in parsers:  # nested subcommands (recal db upgrade|current) too
            for a in parser._actions:
                known.update(a.option_strings)
                if isinstance(a, argparse._SubParsersAction):
                    parsers += a.choices.values()
        assert flags <= known, (command, sorted(flags - known))
