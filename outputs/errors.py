"""Errors of the output layer."""


class OutputError(Exception):
    """An output cannot be written now (another run holds it, or its lock file is not ours); the message names it."""
