"""Overriding a few fields of a frozen parameter dataclass by name, for deployments and ablations.

``tuned(NavigationParams(), {"dock_second_axis": False, "motion.unstick_s": 6})`` is
``NavigationParams`` with those two settings changed (dotted names reach nested parameter
objects) and every other one at its documented default. Values are checked against the type of
the default they replace, and the dataclass's own validation runs on the result, so a typo or
a wrong type is an error when the server starts, not a setting silently ignored.

Standard library only.
"""

from __future__ import annotations

import types
import typing
from collections.abc import Mapping
from dataclasses import fields, is_dataclass, replace
from typing import Any, TypeVar

T = TypeVar("T")

__all__ = ["add_set_argument", "changed", "setting_argument", "tuned"]


def tuned(params: T, overrides: Mapping[str, Any]) -> T:
    """A copy of the frozen dataclass ``params`` with ``overrides`` applied.

    Keys are field names, dotted for fields of nested parameter objects (``"motion.spin_w"``).
    Raises ``ValueError`` naming the key for an unknown name or a value of the wrong type, and
    whatever the dataclass's own checks raise for the result.
    """
    if not is_dataclass(params) or isinstance(params, type):
        raise TypeError(f"tuned() needs a dataclass instance, not {type(params).__name__}")
    cls = type(params).__name__
    names = {f.name for f in fields(params)}
    flat: dict[str, Any] = {}
    nested: dict[str, dict[str, Any]] = {}
    for key, value in overrides.items():
        head, _, rest = key.partition(".")
        if head not in names:
            raise ValueError(f"{cls} has no setting {head!r} (known: {', '.join(sorted(names))})")
        current = getattr(params, head)
        if rest:
            if not is_dataclass(current):
                raise ValueError(f"{cls}.{head} is a value, not a group of settings ({key!r})")
            nested.setdefault(head, {})[rest] = value
        elif is_dataclass(current):
            raise ValueError(f"{cls}.{head} is a group of settings: name one, e.g. '{head}.x'")
        elif value is None and _optional(type(params), head):
            flat[head] = None  # a setting whose type admits None ("float | None")
        else:
            flat[head] = _coerce(current, value, f"{cls}.{head}")
    for head, sub in nested.items():
        flat[head] = tuned(getattr(params, head), sub)
    return replace(params, **flat)


def _optional(cls: type, name: str) -> bool:
    """Whether field ``name`` of dataclass ``cls`` is annotated as admitting ``None``."""
    try:
        hint = typing.get_type_hints(cls).get(name)
    except (NameError, TypeError):  # an annotation that cannot be resolved: not known to
        return False
    return (
        hint is not None
        and type(None) in typing.get_args(hint)
        and (isinstance(hint, types.UnionType) or typing.get_origin(hint) is typing.Union)
    )


def _coerce(current: Any, value: Any, name: str) -> Any:
    """``value`` as the type of ``current`` (the default it replaces), or ``ValueError``."""
    if isinstance(current, bool):
        if isinstance(value, bool):
            return value
    elif isinstance(current, int):
        if isinstance(value, int) and not isinstance(value, bool):
            return value
    elif isinstance(current, float):
        if isinstance(value, int | float) and not isinstance(value, bool):
            return float(value)
    elif isinstance(current, str):
        if isinstance(value, str):
            return value
    elif current is None or isinstance(current, tuple):
        # optional sequences of numbers (zoom factors, block weights)
        if value is None:
            return None
        ints = current is not None and bool(current) and all(isinstance(c, int) for c in current)
        number: Any = int if ints else int | float
        if isinstance(value, list | tuple) and all(
            isinstance(v, number) and not isinstance(v, bool) for v in value
        ):
            return tuple(int(v) if ints else float(v) for v in value)
    kind = type(current).__name__
    if current is None or isinstance(current, tuple):
        kind = "a list of numbers" + (" or null" if current is None else "")
    raise ValueError(f"{name} takes {kind}, not {value!r}")


def changed(params: Any, defaults: Any) -> dict[str, Any]:
    """The settings of the frozen dataclass ``params`` that differ from ``defaults``, by
    dotted name, as :func:`tuned` takes them: ``tuned(defaults, changed(p, defaults)) == p``.
    Tuples come out as lists (JSON)."""
    out: dict[str, Any] = {}
    for f in fields(params):
        value, default = getattr(params, f.name), getattr(defaults, f.name)
        if is_dataclass(value) and not isinstance(value, type):
            out.update({f"{f.name}.{k}": v for k, v in changed(value, default).items()})
        elif value != default:
            out[f.name] = list(value) if isinstance(value, tuple) else value
    return out


def setting_argument(text: str) -> tuple[str, Any]:
    """``NAME=VALUE`` as given on a command line (``--set motion.unstick_s=6``): the name, and
    the value read as JSON (a bare word is a string). For argparse's ``type=``: raises
    ``argparse.ArgumentTypeError`` without ``=``."""
    import argparse
    import json

    name, eq, raw = text.partition("=")
    if not eq or not name.strip():
        raise argparse.ArgumentTypeError(f"--set takes NAME=VALUE, not {text!r}")
    try:
        value = json.loads(raw)
    except json.JSONDecodeError:
        value = raw  # a bare word is a string
    return name.strip(), value


def add_set_argument(parser: Any, help_text: str) -> None:
    """``--set NAME=VALUE`` (repeatable) on an argparse ``parser``, into ``args.settings`` as
    ``(name, value)`` pairs (:func:`setting_argument`)."""
    parser.add_argument(
        "--set",
        dest="settings",
        metavar="NAME=VALUE",
        action="append",
        type=setting_argument,
        default=[],
        help=help_text,
    )
