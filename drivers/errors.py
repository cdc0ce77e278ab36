"""The one input-error hierarchy: every layer's bad-input exception is an :class:`InputError`.

It lives here, in the lowest layer (drivers import neither recal nor service), so recal and the
service can subclass it; the command line maps it to exit code 2 in one place
(``service.cli.main``).
"""

from __future__ import annotations


class InputError(ValueError):
    """Bad input from the user or an unusable design; the message is one line a user can act on.

    The command line prints it after ``recal COMMAND: error:`` with exit code 2 and no traceback.
    """

    def __init__(self, message: object = "") -> None:
        # Keep the one-line promise even when a wrapped OS or library message carries newlines.
        super().__init__(" ".join(str(message).split()))


class DriverInputError(InputError):
    """Bad input to the drivers: unknown port or URL, unusable capture, mis-set format."""
