"""Errors of the runtime package."""


class PolicyError(ValueError):
    """A policy, its exported folder or an observation cannot be used; the message names what and how to fix it."""
