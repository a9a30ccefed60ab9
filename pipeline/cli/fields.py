"""Defaults and help texts of `cnep` options, read from the fields of the settings' dataclasses.

Every setting has one default, a field of its dataclass (`setting(default, help)` in models.config); an
option shows that field's default and help and keeps no value of its own.
"""

from __future__ import annotations

from dataclasses import Field, fields


def field_of(cls: type, name: str) -> Field:
    """The dataclass field `name` of `cls`."""
    return next(f for f in fields(cls) if f.name == name)


def default_of(cls: type, name: str) -> object:
    """The default of field `name` of `cls`."""
    return field_of(cls, name).default


def shown(value: object) -> str:
    """A default as the command line writes it: `128,128` for a tuple of widths."""
    return ",".join(map(str, value)) if isinstance(value, tuple) else str(value)


def help_of(cls: type, name: str, note: str | None = None, default: str | None = None) -> str:
    """The field's help, `note` (what the command line adds) and its default (or `default`), escaped for argparse."""
    text = "; ".join([field_of(cls, name).metadata["help"], *([note] if note else [])])
    return f"{text} (default {default or shown(default_of(cls, name))})".replace("%", "%%")
