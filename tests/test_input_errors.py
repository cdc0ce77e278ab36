"""One input-error hierarchy, one place that maps it to exit 2, one helper that opens input files.

Real files in tmp_path; exit codes through ``service.cli.main.main`` (the console script's entry).
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest

from drivers.errors import DriverInputError, InputError
from recal.errors import RecalInputError
from recal.model.plugins import load_plugin_source
from service.cli.common import open_input, read_text
from service.cli.errors import CliInputError
from service.cli.main import main

CLI = Path(__file__).resolve().parents[1] / "service" / "cli"


@pytest.mark.parametrize("cls", [DriverInputError, RecalInputError, CliInputError])
def test_every_layer_input_error_is_an_input_error(cls) -> None:
    err = cls("bad\n  input\tfile")
    assert isinstance(err, InputError) and isinstance(err, ValueError)
    assert str(err) == "bad input file"  # one line, whatever the wrapped message held


def test_only_main_maps_input_errors_to_exit_2() -> None:
    """No subcommand catches an input error or returns 2 itself: main decides."""
    offenders = []
    for path in sorted(CLI.glob("*.py")):
        if path.name == "main.py":
            continue
        text = path.read_text(encoding="utf-8")
        if re.search(r"except \(?[\w., ]*InputError|return 2\b|exit\(2\)", text):
            offenders.append(path.name)
    assert offenders == []


@pytest.fixture(scope="module")
def positions(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("inputs") / "pos.csv"
    assert main(["simulate", "-o", str(path)]) == 0
    return path


def _error_line(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert err and "Traceback" not in "\n".join(err)
    return err[-1]


def test_each_layer_reaches_exit_2_through_main(tmp_path: Path, positions: Path, capsys) -> None:
    # drivers: a CSV recording whose cells are not numbers
    log = tmp_path / "log.csv"
    log.write_text("t,gx,gy,gz\n0,a,b,c\n")
    assert main(["positions", str(log), "--format", "csv", "-o", str(tmp_path / "o.csv")]) == 2
    assert _error_line(capsys).startswith("recal positions: error: ")
    # engine: a prior with no coefficients
    prior = tmp_path / "prior.json"
    prior.write_text("{}")
    assert main(["calibrate", str(positions), "--prior", str(prior)]) == 2
    assert _error_line(capsys) == (
        f"recal calibrate: error: {prior}: no coefficients found (expected 'gyro' or 'accel')"
    )
    # CLI: a database file that does not exist
    assert main(["db", "current", "--database", f"sqlite:///{tmp_path / 'none.db'}"]) == 2
    assert _error_line(capsys).startswith("recal db: error: database file ")


def test_open_input_names_each_failure(tmp_path: Path) -> None:
    with pytest.raises(CliInputError, match=r"^positions file .*nope.csv does not exist$"):
        open_input(tmp_path / "nope.csv", "positions file")
    with pytest.raises(CliInputError, match=r"is a directory, not a file$"):
        open_input(tmp_path, "positions file")
    empty = tmp_path / "empty.csv"
    empty.write_bytes(b"")
    with pytest.raises(CliInputError, match=r"^positions file .*empty.csv: the file is empty$"):
        open_input(empty, "positions file")
    with open_input(empty, "log", empty_ok=True) as fh:
        assert fh.read() == b""
    latin = tmp_path / "latin.csv"
    latin.write_bytes(b"a,b\n1,2\n\xe9t\xe9\n")
    with pytest.raises(CliInputError, match=r"is not UTF-8 text \(byte 0xe9 on line 3\)$"):
        read_text(latin, "positions file")
    bom = tmp_path / "bom.csv"
    bom.write_bytes(b"\xef\xbb\xbfa,b\n")
    assert read_text(bom) == "a,b\n"


@pytest.mark.skipif(os.geteuid() == 0, reason="root reads files whatever their mode")
def test_open_input_permission_denied(tmp_path: Path) -> None:
    locked = tmp_path / "locked.json"
    locked.write_text("{}")
    locked.chmod(0)
    with pytest.raises(CliInputError, match="permission denied"):
        open_input(locked, "coefficients file")


@pytest.mark.parametrize(
    ("name", "content", "reason"),
    [
        ("notes.bin", b"\x00\x01binary notes", "is not a Python file (expected FILE.py)"),
        ("empty.py", b"", "the file is empty"),
        ("broken.py", b"def (:\n", "is not valid Python: invalid syntax on line 1"),
        ("nul.py", b"TERMS = []\x00\n", "is not"),
        ("latin.py", b"# \xe9\nTERMS = []\n", "is not UTF-8 text"),
        ("raises.py", b"import no_such_module_here\n", "failed to load: ModuleNotFoundError"),
        ("exits.py", b"raise SystemExit(3)\n", "failed to load: SystemExit: 3"),
        ("noterms.py", b"X = 1\n", "must define TERMS = [recal.model.terms.Term, ...]"),
        ("missing.py", None, "does not exist"),
        ("folder.py", "dir", "is a directory, not a file"),
    ],
)
def test_bad_plugin_files_exit_2_with_one_line(
    tmp_path: Path, positions: Path, capsys, name, content, reason
) -> None:
    plugin = tmp_path / name
    if content == "dir":
        plugin.mkdir()
    elif content is not None:
        plugin.write_bytes(content)
    assert main(["diagnose", str(positions), "--plugin", str(plugin)]) == 2
    line = _error_line(capsys)
    assert line.startswith(f"recal diagnose: error: plugin {plugin}") and reason in line


def test_plugin_from_source_registers_its_terms() -> None:
    source = (
        "from dataclasses import dataclass\n"
        "from recal.model.terms import Term\n"
        "@dataclass(frozen=True)\n"
        "class CrossBias(Term):\n"
        "    def nonlinear(self, p, x, ctx):\n"
        "        out = 0 * x\n"
        "        out[..., 2] = p[:, None, 0] * x[..., 0]\n"
        "        return out\n"
        "TERMS = [CrossBias('gyro.my_cross', 'gyro', ('c',), '1', (1e-4,), (0.0,), 'z from x')]\n"
    )
    try:
        (term,) = load_plugin_source(source, "/somewhere/my_lin.py")
    except RecalInputError as exc:  # the Term signature is the engine's; say what broke
        pytest.fail(f"plugin did not load: {exc}")
    assert term.name == "gyro.my_cross"
    assert type(term).__module__ == "recal_plugin_my_lin"  # pickling finds the class by it
