"""The command line's own input error (bad flags, files that cannot be opened).

Like the drivers' and the engine's, it is a :class:`drivers.errors.InputError`: the one handler
in ``service.cli.main`` maps every such error to exit code 2 with a one-line reason. Imported
only when a command runs, so building the parser stays light.
"""

from __future__ import annotations

from drivers.errors import InputError

__all__ = ["CliInputError", "InputError"]


class CliInputError(InputError):
    """Bad input detected by the CLI layer itself (exit code 2)."""
