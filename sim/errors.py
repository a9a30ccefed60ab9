"""The simulator's error: one line saying what is missing and how to get it."""


class SimError(RuntimeError):
    """The simulator cannot run here (no rendering backend, the `sim` extra missing)."""
