"""Entry point of the ``recal`` console script.

Each subcommand lives in its own module under ``service.cli`` and exposes
``register(subparsers) -> argparse.ArgumentParser``; the parser's default ``func`` takes the
parsed namespace and returns the process exit code.

Building the parser imports only argparse-level modules: each subcommand module imports numpy,
the engine and the drivers inside its ``run``, so ``recal --help`` and a command pay only for
what they use.

Exit codes (docs/reference.md#cli): 0 success, 2 bad input or unusable design (one line on
stderr, no traceback), 1 internal error.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

# Module names under service.cli, in the order they appear in --help.
SUBCOMMANDS: tuple[str, ...] = (
    "simulate",
    "calibrate",
    "diagnose",
    "positions",
    "noise",
    "drift",
    "navigate",
    "apply",
    "export",
    "predict",
    "record",
    "serve",
    "db",
    "sync",
    "fleet",
    "demo",
)


def _is_input_error(exc: BaseException) -> bool:
    # imported only when a command has failed: building the parser stays light
    from drivers.errors import InputError

    return isinstance(exc, InputError)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="recal",
        description="In-field recalibration of FOG gyro and accelerometer triads from static positions.",
    )
    parser.add_argument("--version", action="version", version=f"recal {_version()}")
    parser.add_argument("--debug", action="store_true", help=_DEBUG_HELP)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in SUBCOMMANDS:
        try:
            module = importlib.import_module(f"service.cli.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"service.cli.{name}":
                continue  # subcommand not built yet
            raise
        module.register(sub)
    for command in sub.choices.values():
        _accept_debug(command)
    return parser


_DEBUG_HELP = "show tracebacks on internal errors (also RECAL_DEBUG=1)"


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("fog-recal")
    except PackageNotFoundError:  # run from a checkout that was never installed
        return "unknown"


def _accept_debug(parser: argparse.ArgumentParser) -> None:
    """Let ``--debug`` follow the subcommand too (``recal calibrate X.csv --debug``), in nested
    subcommands as well. SUPPRESS: absent there, it leaves the top-level value alone."""
    if "--debug" not in parser._option_string_actions:
        parser.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                            help=_DEBUG_HELP)  # fmt: skip
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for nested in action.choices.values():
                _accept_debug(nested)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help(sys.stderr)
        return 2
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print(f"recal {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 0
    except Exception as exc:  # noqa: BLE001 - the one place exit codes 2 and 1 are decided
        if _is_input_error(exc):
            # bad input from any layer (drivers, engine, CLI): one line, no traceback
            print(f"recal {args.command}: error: {exc}", file=sys.stderr)
            return 2
        if args.debug or os.environ.get("RECAL_DEBUG"):
            import traceback

            traceback.print_exc()
        print(
            f"recal {args.command}: internal error: {type(exc).__name__}: {exc} "
            "(run with --debug for the traceback)",
            file=sys.stderr,
        )
        return 1


if __name__ == "__main__":
    sys.exit(main())
