"""Errors the drivers raise for bad user input (the CLI maps them to exit code 2)."""

from __future__ import annotations


class DriverInputError(Exception):
    """Bad input from the user: unknown port or URL, unusable capture, mis-set format.

    The message is one line in plain words; the CLI prints it as is, with no traceback.
    """

    def __init__(self, message: str) -> None:
        # Keep the one-line promise even when a wrapped OS message carries newlines.
        super().__init__(" ".join(str(message).split()))
