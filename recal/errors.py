"""Exceptions raised by the numerical engine."""


class RecalInputError(ValueError):
    """Bad input or an unusable design; the message is one line a user can act on.

    The command line maps it to exit code 2 with the message on stderr and no traceback.
    """
