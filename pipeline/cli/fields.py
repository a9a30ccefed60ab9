"""`cnep` options read from the fields of the settings' dataclasses, and the settings built back from them.

Every setting has one default, a field of its dataclass (`setting(default, help)` in models.config); an
option shows that field's default and help and keeps no value of its own. `options(cls)` walks a stage's
config: each field with a help text is an option (`--name`, or the field's `option` name), and a field that
holds another config (a `default_factory` making a dataclass, such as `TrainStageConfig.training`) is walked in
turn, its options grouped under the field's name. `build(cls, chosen)` makes the config of chosen values, nested
the same way, so a field added to any of these dataclasses is an option, a `--config` key and a value the stage
receives with no other edit.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import MISSING, Field, dataclass, fields, is_dataclass

from cnep.models.config import in_message


@dataclass(frozen=True)
class Option:
    """One option: name (with underscores: the `--config` key), field (its help), default (the field's, or that of
    the nested config holding it: the demo's model has its own number of experts), group (the name of that nested
    config, None for the stage's own fields)."""

    name: str
    field: Field
    default: object
    group: str | None

    @property
    def flag(self) -> str:
        return f"--{self.name.replace('_', '-')}"

    @property
    def kind(self) -> type:
        """The type its value has, from the field's annotation (a string where the module defers annotations)."""
        annotation = str(self.field.type)
        if annotation.startswith("tuple"):
            return tuple
        return next(kind for kind in (bool, float, int, str) if kind.__name__ in annotation)

    @property
    def is_flag(self) -> bool:
        """A switch (`--force`; `--no-NAME` too where it is on by default)."""
        return self.kind is bool


def option_name(f: Field) -> str:
    """The name of a setting's option (with underscores): the field's, or the `option` it was given."""
    return f.metadata.get("option", f.name)


def nested(f: Field | Callable[[], object]) -> object | None:
    """The config a field (or a config's factory) holds by default (its default_factory's dataclass instance),
    or None for a setting."""
    factory = f if callable(f) else f.default_factory
    if factory is MISSING:
        return None
    made = factory()
    return made if is_dataclass(made) else None


def options(cls: type, group: str | None = None, defaults: object | None = None) -> list[Option]:
    """Every option of config class `cls` (whose default values are those of `defaults` where given), its nested
    configs' included, in field order."""
    found = []
    for f in fields(cls):
        inner = nested(f)
        if inner is not None:
            found += options(type(inner), f.name, inner)
        elif "help" in f.metadata:
            default = f.default if defaults is None else getattr(defaults, f.name)
            found.append(Option(option_name(f), f, default, group))
    return found


def build(make: Callable[..., object], chosen: dict[str, object], **given: object):
    """`make(**fields)`: the config with the options' values in `chosen` (by option name; others keep their
    defaults) and the fields in `given`, its nested configs made the same way by their default_factory (a class,
    or a `functools.partial` of one: each field it leaves out keeps its default, derived ones included, such as the
    loss weights that follow the number of experts)."""
    values = dict(given)
    for f in fields(nested(make) if not isinstance(make, type) else make):
        if f.name in given:
            continue
        if nested(f) is not None:
            values[f.name] = build(f.default_factory, chosen)
        elif "help" in f.metadata and option_name(f) in chosen:
            values[f.name] = chosen[option_name(f)]
    return make(**values)


def chosen_options(cls: type, args: argparse.Namespace) -> dict[str, object]:
    """The options of config class `cls` given on the parsed command line `args` (option name -> value)."""
    return {option.name: getattr(args, option.name) for option in options(cls) if hasattr(args, option.name)}


def field_of(cls: type, name: str) -> Field:
    """The dataclass field `name` of `cls`."""
    return next(f for f in fields(cls) if f.name == name)


def default_of(cls: type, name: str) -> object:
    """The default of field `name` of `cls`."""
    return field_of(cls, name).default


def shown(value: object) -> str:
    """A default as the command line writes it: `128,128` for a tuple of widths."""
    return ",".join(map(str, value)) if isinstance(value, tuple) else str(value)


def shown_default(option: Option) -> str:
    """How an option's default reads: as its field says to show it (a setting's `shown`), else its value."""
    return option.field.metadata.get("shown") or shown(option.default)


def help_of(cls: type, name: str, note: str | None = None, default: str | None = None) -> str:
    """The field's help, `note` (what the command line adds) and its default (or `default`), escaped for argparse."""
    return _help(field_of(cls, name), note, default or shown(default_of(cls, name)))


def _help(f: Field, note: str | None = None, default: str | None = None) -> str:
    text = "; ".join([f.metadata["help"], *([note] if note else [])])
    return f"{text} (default {default})".replace("%", "%%")


INT_LIMIT = 2**63  # an integer setting lies strictly within +-this (int64, what numpy and torch take)


def integer(text: str) -> int:
    """An integer option's value, as argparse reads it (ValueError: argparse says "invalid integer value")."""
    value = int(text)
    if not -INT_LIMIT < value < INT_LIMIT:
        raise argparse.ArgumentTypeError(
            f"expected an integer from {-(INT_LIMIT - 1)} to {INT_LIMIT - 1}, got {in_message(value)}"
        )
    return value


def integers(text: str) -> tuple[int, ...]:
    """A list option's value, comma-separated integers (`128,128`), as argparse reads it."""
    try:
        return tuple(integer(w) for w in text.split(","))
    except (ValueError, argparse.ArgumentTypeError):
        raise argparse.ArgumentTypeError(
            f"expected comma-separated whole numbers such as 128,128 or 0, got {in_message(text)}"
        ) from None


def add_options(
    parser: argparse.ArgumentParser,
    found: list[Option],
    notes: dict[str, str] | None = None,
    defaults: dict[str, str] | None = None,
) -> None:
    """Add `found` to `parser`, nested ones in a group per config; an option not given stays out of the parsed
    args (so a config file and the defaults fill it). notes: what the command line adds to an option's help;
    defaults: how to show a default the field's value does not say (such as None)."""
    notes, defaults, groups = notes or {}, defaults or {}, {None: parser}
    for option in found:
        if option.group not in groups:
            groups[option.group] = parser.add_argument_group(option.group)
        group = groups[option.group]
        if option.is_flag:
            action = "store_true" if option.default is False else argparse.BooleanOptionalAction
            group.add_argument(
                option.flag, action=action, default=argparse.SUPPRESS, help=option.field.metadata["help"]
            )
            continue
        group.add_argument(
            option.flag,
            type={tuple: integers, int: integer}.get(option.kind, option.kind),
            default=argparse.SUPPRESS,
            choices=option.field.metadata.get("choices"),
            help=_help(option.field, notes.get(option.name), defaults.get(option.name) or shown_default(option)),
        )
