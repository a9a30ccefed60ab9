"""Errors of the perception package."""


class PerceptionError(Exception):
    """Frames or weights cannot be used; the message names the file and says how to fix it."""
