"""Command-line options derived from the config dataclasses, so every setting has one source.

A dataclass field whose metadata has a "help" text becomes the option ``--field-name`` with the field's
default; its type decides how the option is parsed: ``int``, a finite ``float`` (``float | None`` too),
``str``, ``Literal[...]`` (the choices), ``bool`` (``--name`` / ``--no-name``) and tuples (``nargs``).
Metadata may add "metavar", "choices", "flag" (another option name) and "min" / "max" (inclusive bounds
checked at parse time). A subclass that only changes a field's default keeps its base class's metadata.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import types
import typing
from typing import Any, Literal, get_args, get_origin

GROUP_TITLES = {  # what each config's options set, as the help titles them
    "ScenarioConfig": "scenario (the simulated world, path and camera)",
    "TrackerConfig": "front-end",
    "OdometryConfig": "odometry",
    "SourceOptions": "input",
    "SweepConfig": "sweep",
    "Workers": "parallel work",
    "MagicWarpConfig": "network",
    "TrainConfig": "training",
    "AdaptConfig": "homographic adaptation and training",
    "DetectorEvalConfig": "evaluation",
    "WarpEvalConfig": "evaluation",
    "RealImagesConfig": "evaluation",
    "PipelineBenchConfig": "benchmark",
    "DriftConfig": "drift",
}


def number_type(kind: type, low: float | None = None, high: float | None = None, name: str = ""):
    """An argparse type: a finite number of ``kind`` within [low, high]."""

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            expected = "an integer" if kind is int else "a number"
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"must be finite, got {text!r}")
        if (low is not None and value < low) or (high is not None and value > high):
            bounds = f"[{'-inf' if low is None else low}, {'inf' if high is None else high}]"
            raise argparse.ArgumentTypeError(f"must lie in {bounds}, got {text!r}")
        return value

    parse.__name__ = name or kind.__name__  # argparse names the type in its messages
    return parse


def _unwrap_optional(hint: Any) -> Any:
    if get_origin(hint) in (typing.Union, types.UnionType):
        args = [a for a in get_args(hint) if a is not type(None)]
        return args[0] if len(args) == 1 else hint
    return hint


def _argument(hint: Any, meta: dict) -> dict:
    """argparse keyword arguments of a field with type ``hint``."""
    hint = _unwrap_optional(hint)
    low, high = meta.get("min"), meta.get("max")
    if get_origin(hint) is Literal:
        choices = get_args(hint)
        return {"choices": choices, "type": type(choices[0])}
    if hint is bool:
        return {"action": argparse.BooleanOptionalAction}
    if get_origin(hint) is tuple:
        items = get_args(hint)
        item = items[0]
        nargs: int | str = "+" if len(items) == 2 and items[1] is Ellipsis else len(items)
        if get_origin(item) is Literal:
            return {"nargs": nargs, "choices": get_args(item)}
        kind = item if item in (int, float) else str
        parse = number_type(kind, low, high, kind.__name__) if kind in (int, float) else str
        return {"nargs": nargs, "type": parse}
    if hint in (int, float):
        return {"type": number_type(hint, low, high, hint.__name__)}
    return {"type": str}


def _metadata(config: type, name: str) -> dict:
    """The metadata of field ``name``: its own, or that of the nearest base class that documents it."""
    for cls in config.__mro__:
        if dataclasses.is_dataclass(cls):
            fields = {f.name: f for f in dataclasses.fields(cls)}
            if name in fields and "help" in fields[name].metadata:
                return dict(fields[name].metadata)
    return {}


def options_of(config: type) -> list[str]:
    """The names of the fields of ``config`` that are options."""
    return [f.name for f in dataclasses.fields(config) if "help" in _metadata(config, f.name)]


def add_options(parser: argparse.ArgumentParser, config: type, exclude: tuple[str, ...] = ()) -> None:
    """Add an option for every documented field of the dataclass ``config`` (but ``exclude``)."""
    hints = typing.get_type_hints(config)
    group = parser.add_argument_group(GROUP_TITLES.get(config.__name__, f"{config.__name__} options"))
    for field in dataclasses.fields(config):
        meta = _metadata(config, field.name)
        if not meta or field.name in exclude:
            continue
        flag = meta.get("flag", "--" + field.name.replace("_", "-"))
        kwargs = _argument(hints[field.name], meta)
        kwargs.update({key: meta[key] for key in ("metavar", "choices") if key in meta})
        default = field.default if field.default is not dataclasses.MISSING else field.default_factory()
        text = meta["help"] + (f" (at most {_as_typed(meta['max'])})" if "max" in meta else "")
        group.add_argument(flag, dest=field.name, default=default, help=text, **kwargs)


def _as_typed(value: float) -> str:
    """A bound as one would type it: whole numbers in full (4294967295, not 4.29497e+09)."""
    return str(int(value)) if float(value).is_integer() else f"{value:g}"


def from_args(config: type, args: argparse.Namespace, **overrides: Any):
    """The dataclass ``config`` built from the parsed options it offers (tuples for sequences), with
    ``overrides``; a ValueError of its own checks propagates."""
    hints = typing.get_type_hints(config)
    values = {}
    for name in options_of(config):
        if name in overrides or not hasattr(args, name):
            continue
        value = getattr(args, name)
        origin = get_origin(_unwrap_optional(hints[name]))
        values[name] = tuple(value) if origin is tuple and value is not None else value
    return config(**values, **overrides)
