"""Errors the CLI reports as one line (``aibo: error: ...``, exit status 2)."""


class CLIError(Exception):
    """A user error: printed as one line, exit status 2."""
