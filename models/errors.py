"""Errors of the movement-model package."""


class ConfigError(ValueError):
    """A configuration value breaks a rule; the message states the rule and the offending value."""
