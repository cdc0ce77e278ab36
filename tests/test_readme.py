"""The README's synopsis lists every flag that its own examples use, and only flags that exist;
its bash examples run, in order, from a fresh folder laid out like the project's."""

from __future__ import annotations

import argparse
import os
import re
import shlex
import subprocess
import sys
import time
from pathlib import Path

import pytest

from service.cli.main import build_parser

PROJECT = Path(__file__).resolve().parents[1]
README = PROJECT / "README.md"
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


# ---- the examples run ---------------------------------------------------------------------------
#: README commands not run here, by a fragment of the command, with the reason. Nothing else is
#: skipped: a new example runs unless it is added here.
NOT_RUN = {
    "pip install": "installs the package (the tests run the installed one)",
    "recal demo": "the whole service on a 20-minute session: about a minute (tests/service cover it)",
    "--paper": "the seeds' swarm on the exact objective: about 40 s",
    "recal serve": "a daemon that runs until stopped",
    "sudo ": "installs the service on a host",
    "secrets.token_urlsafe": "part of the host installation",
    "/dev/ttyUSB0": "a live serial port",
}
#: Options naming a file a command writes.
OUTPUT_OPTIONS = (
    "-o",
    "--output",
    "--capture",
    "--truth-out",
    "--report",
    "--recording",
    "--track",
)
COMMAND_TIMEOUT_S = 60.0
SHARED = PROJECT.parent / "shared"


def _commands(text: str) -> list[tuple[str, int]]:
    """(command line, expected exit code) of every line of the README's bash blocks, in order,
    continuations joined; the line's comment 'exit N' gives its code (default 0). A line runs as
    one unit: `a && b` stops at a's failure, as it would for the reader."""
    out = []
    for block in re.findall(r"```bash\n(.*?)```", text, re.DOTALL):
        for line in block.replace("\\\n", " ").splitlines():
            code, _, comment = line.partition("#")
            if code.strip():
                m = re.search(r"\bexit (\d+)", comment)
                out.append((" ".join(code.split()), int(m.group(1)) if m else 0))
    return out


def _outputs(command: str) -> list[str]:
    words = shlex.split(command)
    return [b for a, b in zip(words, words[1:], strict=False) if a in OUTPUT_OPTIONS]


def test_every_example_writes_its_own_files() -> None:
    """No two README commands write the same file (a positions file's slews side file would be
    picked up by the other section's calibrate)."""
    written = [f for cmd, _ in _commands(README.read_text()) for f in _outputs(cmd)]
    assert written, "no README command writes a file?"
    assert len(written) == len(set(written)), sorted(f for f in written if written.count(f) > 1)


@pytest.mark.slow
def test_the_readme_examples_run_in_order(tmp_path: Path) -> None:
    """Every README command not listed in NOT_RUN exits with the code it claims, run in a fresh
    folder that sees the project's docs/ and ../shared/ (read only) and nothing else."""
    work = tmp_path / "project"
    work.mkdir()
    (work / "docs").symlink_to(PROJECT / "docs")
    if SHARED.is_dir():
        (tmp_path / "shared").symlink_to(SHARED)
    elif os.environ.get("CI"):
        pytest.fail(f"shared data folder {SHARED} is missing under CI")
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    env.pop("CI", None)  # a README user has no CI set: no test-only strictness in the commands
    missing: set[str] = set()  # files a command not run here would have written
    ran, failures = 0, []
    took: dict[str, float] = {}
    for command, expected in _commands(README.read_text()):
        skip = next((why for frag, why in NOT_RUN.items() if frag in command), None)
        words = set(shlex.split(command))
        if skip is None and not SHARED.is_dir() and any("../shared/" in w for w in words):
            skip = "shared data absent"
        if skip is None and words & missing:
            skip = "reads a file of a command not run here"
        if skip is not None:
            missing.update(_outputs(command))
            continue
        t0 = time.perf_counter()
        try:
            proc = subprocess.run(["bash", "-c", command], cwd=work, env=env, capture_output=True,
                                  text=True, timeout=COMMAND_TIMEOUT_S)  # fmt: skip
        except subprocess.TimeoutExpired:
            failures.append(f"{command}: over {COMMAND_TIMEOUT_S:.0f} s")
            continue
        ran += 1
        took[command] = time.perf_counter() - t0
        if proc.returncode != expected:
            tail = proc.stderr.strip().splitlines()[-3:]
            failures.append(f"{command}: exit {proc.returncode}, README says {expected}: {tail}")
        elif expected == 2:  # a refusal is one line on stderr (common rules)
            assert proc.stderr.strip().splitlines()[-1].startswith("recal "), proc.stderr
        assert time.perf_counter() - t0 < COMMAND_TIMEOUT_S
    slowest = sorted(took.items(), key=lambda kv: -kv[1])[:5]
    print("slowest README commands:", *(f"{t:.1f} s  {c}" for c, t in slowest), sep="\n  ")
    assert not failures, "\n".join(failures)
    assert ran >= 12, f"only {ran} README commands ran"


def test_ci_runs_the_readme_test_command() -> None:
    """.ci/run calls exactly the README's second command, so a missing install step shows."""
    blocks = re.findall(r"```bash\n(.*?)```", README.read_text(), re.S)
    command = blocks[1].strip()
    ci = (PROJECT / ".ci" / "run").read_text().splitlines()
    marker = next(i for i, line in enumerate(ci) if "README test command" in line)
    assert ci[marker + 1].startswith(command), (ci[marker + 1], command)
