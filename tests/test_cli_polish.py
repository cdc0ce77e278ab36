"""Command-line polish: ``recal --version``, ``--debug`` after the subcommand, a help text for
every option of ``demo`` and ``serve``, and the settings listed by ``recal serve --help``."""

from __future__ import annotations

import argparse
import subprocess
import sys
from importlib.metadata import version
from pathlib import Path

import pytest
from pydantic import BaseModel

from service.cli.main import build_parser, main
from service.config import Settings


def _help(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    assert exit_.value.code == 0
    return capsys.readouterr().out


def test_version_is_the_installed_distribution(capsys: pytest.CaptureFixture[str]) -> None:
    assert _help(["--version"], capsys) == f"recal {version('fog-recal')}\n"
    script = Path(sys.executable).with_name("recal")
    done = subprocess.run([str(script), "--version"], capture_output=True, text=True, timeout=60)
    assert (done.returncode, done.stdout, done.stderr) == (0, f"recal {version('fog-recal')}\n", "")


@pytest.mark.parametrize(
    "argv, debug",
    [
        (["calibrate", "p.csv"], False),
        (["--debug", "calibrate", "p.csv"], True),
        (["calibrate", "p.csv", "--debug"], True),
        (["calibrate", "--debug", "p.csv"], True),
        (["db", "--debug", "current"], True),
        (["db", "current", "--debug"], True),
        (["serve", "--config", "x.toml", "--debug"], True),
    ],
)
def test_debug_is_accepted_before_and_after_the_subcommand(argv: list[str], debug: bool) -> None:
    assert build_parser().parse_args(argv).debug is debug


def test_debug_after_the_subcommand_shows_the_traceback(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    def boom(args: argparse.Namespace) -> int:
        raise RuntimeError("boom")

    monkeypatch.delenv("RECAL_DEBUG", raising=False)
    monkeypatch.setattr("service.cli.db.run_current", boom)
    assert main(["db", "current", "--database", "sqlite://"]) == 1
    err = capsys.readouterr().err
    assert "Traceback" not in err and "internal error: RuntimeError: boom" in err
    assert main(["db", "current", "--database", "sqlite://", "--debug"]) == 1
    assert "Traceback" in capsys.readouterr().err


@pytest.mark.parametrize(
    "command",
    ["demo", "serve", "db", "fleet", "simulate", "positions", "record", "navigate", "predict"],
)
def test_every_option_has_a_help_text(command: str) -> None:
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    parsers = [sub.choices[command]]
    for parser in parsers:  # nested subcommands too
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                parsers += action.choices.values()
            elif action.option_strings:
                assert action.help and action.help != argparse.SUPPRESS, (command, action.dest)


def test_serve_help_lists_every_setting(capsys: pytest.CaptureFixture[str]) -> None:
    out = _help(["serve", "--help"], capsys)
    flat = " ".join(out.split())  # descriptions are wrapped to the terminal
    assert "service/config.py" not in out  # no pointer at the source: the settings themselves
    assert "RECAL_<SECTION>__<KEY>" in flat
    for key, info in Settings.model_fields.items():
        model = info.annotation
        if isinstance(model, type) and issubclass(model, BaseModel):
            assert f"[{key}]" in out
            fields = model.model_fields
        else:
            fields = {key: info}
        for name, field in fields.items():
            assert f"\n  {name} = " in out, name
            assert " ".join(field.description.split()) in flat, name
    assert '\n  url = "loop://"\n' in out
    assert "\n  rate_hz = 1000.0  (> 0, <= 5000)\n" in out
    assert '\n  format = "kvh-a"  (one of kvh-a, kvh-b, kvh-c, csv)\n' in out
    assert '\n  trigger = ["drift", "information"]  (any of drift, information, count)\n' in out
    assert "\n  token = unset\n" in out and "\n  use_slews = true\n" in out


def test_top_level_help_lists_db(capsys: pytest.CaptureFixture[str]) -> None:
    out = _help(["--help"], capsys)
    assert "--version" in out and "\n    db " in out


@pytest.mark.parametrize(
    "argv",
    [
        ["--latitude", "200"],
        ["--latitude", "nan"],
        ["--height", "inf"],
        ["--positions", "0", "--design", "random"],
        ["--window", "-5"],
        ["--trajectory", "voyage", "--latitude", "-91"],
    ],
)
def test_bad_simulate_values_are_one_line_exit_2(
    argv: list[str], tmp_path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out.csv"
    flag = ["--recording", str(out)] if "--trajectory" in argv else ["-o", str(out)]
    assert main(["simulate", *argv, *flag]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("recal simulate: error: "), err
    assert not out.exists()  # nothing half-written


def test_positions_warns_when_the_rate_setting_is_wrong(
    tmp_path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A KVH outputs physical units: read at a tenth of its rate, the gyro shows a tenth of
    Earth's rate, and the warning names --rate and the rate the windows suggest."""
    cap = tmp_path / "cap.bin"
    assert main(["simulate", "--capture", str(cap), "--rate", "100", "--first-hold", "40"]) == 0
    capsys.readouterr()
    for rate, warned in (("100", False), ("10", True)):
        out = tmp_path / f"pos{rate}.csv"
        args = ["positions", str(cap), "--format", "kvh-a", "--rate", rate, "-o", str(out)]
        assert main(args) == 0
        err = capsys.readouterr().err
        assert ("warning: at rest the gyro reads" in err) == warned, err
        if warned:
            assert "--rate 10 (these windows suggest 100 Hz)" in err


@pytest.mark.slow
def test_paper_mode_excess_is_blamed_on_the_solver_when_lm_fits(
    tmp_path, capsys: pytest.CaptureFixture[str]
) -> None:
    """--paper swarms stop short of the minimum: the note says so (LM from the swarm's solution
    fits to the noise) instead of sending the user to diagnose; MC std is explained."""
    pos = tmp_path / "pos.csv"
    assert main(["simulate", "--seed", "1", "-o", str(pos)]) == 0
    args = ["calibrate", str(pos), "--latitude", "45", "--method", "nafsa", "--mc", "10"]
    assert main([*args, "--paper"]) == 0
    out = capsys.readouterr().out
    # the convergence check (LM from the swarm's answer) says so, whatever chi2_red is
    assert "converged: NO -- the nafsa answer is" in out and "the swarm stopped short" in out
    assert "recal diagnose`" not in out
    assert "MC std: the spread of the coefficient over the 10 Monte Carlo runs" in out


@pytest.mark.parametrize(
    "extra, expected",
    [
        ([], None),  # the method's own defaults (calibrate picks them)
        (["--fish", "30"], (30, 12)),  # the default whitened NAFSA: 12 iterations per cycle
        (["--iterations", "60"], (50, 60)),  # asked for explicitly: kept, even at Table 1's 60
        (["--fish", "30", "--paper"], (30, 60)),  # the seeds' phases: Table 1's 60
        (["--fish", "20", "--method", "safsa"], (20, 60)),
    ],
)
def test_swarm_size_flags_default_to_the_methods_own(extra: list[str], expected) -> None:
    from service.cli.calibrate import options_from_args

    parser = build_parser()
    argv = ["calibrate", "p.csv", "--latitude", "45"]
    if "--method" not in extra:
        argv += ["--method", "nafsa"]
    opt = options_from_args(parser.parse_args(argv + extra))
    cfg = opt.swarm_config
    assert (None if cfg is None else (cfg.fish, cfg.iterations)) == expected
    if "--paper" in extra:
        assert cfg.cf_mode == "literal"
