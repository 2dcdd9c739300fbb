"""Reading the fields of dataset files, each checked, with a one-line ``SourceError`` that names the file,
the line and the field: text tables (TUM's space-separated lists, EuRoC's CSV), YAML mappings, times,
poses and the paths of image files."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import yaml

from deepslam.geometry import pose_matrix
from deepslam.inputs.source import SourceError

DECIMAL_SECONDS = re.compile(r"^\d+(\.\d+)?$")
UNIT_QUATERNION_TOLERANCE = 1e-2  # |q| may differ from 1 by this much (files round their digits)


def rows(path: Path, fields: tuple[str, ...], separator: str | None = None) -> list[tuple[int, list[str]]]:
    """The data lines of a text table (blank lines and "#" comments skipped), as (line number, fields),
    each with at least the named ``fields``."""
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as error:
        raise SourceError(f"{path}: cannot read it ({error})") from None
    table = []
    for number, line in enumerate(text.splitlines(), 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        values = [v.strip() for v in (line.split(separator) if separator else line.split())]
        if len(values) < len(fields) or not all(values[: len(fields)]):
            missing = next(name for i, name in enumerate(fields) if i >= len(values) or not values[i])
            raise SourceError(f"{path} line {number}: no {missing} (expected {', '.join(fields)})")
        table.append((number, values))
    return table


def number(text: str, where: str) -> float:
    """A finite number, or a ``SourceError`` naming ``where`` (file, line, field)."""
    try:
        value = float(text)
    except ValueError:
        raise SourceError(f"{where}: {text!r} is not a number") from None
    if not math.isfinite(value):
        raise SourceError(f"{where}: {text!r} is not finite")
    return value


def seconds_ns(text: str, where: str) -> int:
    """Integer nanoseconds of non-negative decimal seconds such as "1305031102.175304" (no float rounding)."""
    if not DECIMAL_SECONDS.match(text):
        raise SourceError(f"{where}: {text!r} is not a time in seconds (digits, one optional decimal point)")
    whole, _, fraction = text.partition(".")
    return int(whole) * 1_000_000_000 + int((fraction + "000000000")[:9])


def nanoseconds(text: str, where: str) -> int:
    """Non-negative integer nanoseconds."""
    if not text.isdigit():
        raise SourceError(f"{where}: {text!r} is not a time in nanoseconds (digits only)")
    return int(text)


def pose(position: list[str], quaternion_xyzw: list[str], where: str) -> np.ndarray:
    """``T_world_cam`` (4, 4) of a position and a unit quaternion (x, y, z, w), all fields checked."""
    p = np.array([number(v, f"{where}, position") for v in position])
    q = np.array([number(v, f"{where}, quaternion") for v in quaternion_xyzw])
    norm = float(np.linalg.norm(q)) if np.all(np.abs(q) <= 2) else np.inf  # huge parts would overflow the norm
    if abs(norm - 1) > UNIT_QUATERNION_TOLERANCE:
        raise SourceError(f"{where}: the quaternion {q.tolist()} is not a unit quaternion (norm {norm:.3g})")
    return pose_matrix(p, q)


def inside(root: Path, name: str, where: str) -> Path:
    """The file ``name`` relative to ``root``, which it must not leave (no absolute paths, no "..")."""
    path = (root / name).resolve()
    if Path(name).is_absolute() or not path.is_relative_to(root.resolve()):
        raise SourceError(f"{where}: {name!r} lies outside {root}")
    return root / name


def yaml_mapping(path: Path, text: str | None = None) -> dict:
    """A YAML file whose top level is a mapping (``text``: its contents, if already read and mended)."""
    try:
        data = yaml.safe_load(path.read_text() if text is None else text)
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as error:
        raise SourceError(f"{path}: cannot read it ({' '.join(str(error).split())})") from None
    if not isinstance(data, dict):
        raise SourceError(f"{path}: expected a mapping of names to values, got {type(data).__name__}")
    return data


def unknown_keys(path: Path, data: dict, known: tuple[str, ...]) -> None:
    """Raise SourceError naming the first key of the YAML file ``path`` (read as ``data``) that is not one of
    ``known``, with its line, and the known ones."""
    unknown = [key for key in data if key not in known]
    if not unknown:
        return
    node = yaml.compose(path.read_text())
    lines = {str(key.value): key.start_mark.line + 1 for key, _ in node.value}
    raise SourceError(
        f"{path}, line {lines.get(str(unknown[0]), '?')}: unknown key {unknown[0]!r} (known: {', '.join(known)})"
    )


def yaml_number(data: dict, key: str, where: Path) -> float:
    """The finite number ``data[key]`` (not a boolean; "1e-3", which YAML 1.1 reads as text, counts)."""
    if key not in data:
        raise SourceError(f"{where}: {key} is missing")
    value = _as_number(data.get(key))
    if value is None:
        raise SourceError(f"{where}: {key} must be a finite number, got {data.get(key)!r}")
    return value


def yaml_numbers(data: dict, key: str, where: Path, count: int | None = None) -> list[float]:
    """The list of finite numbers ``data[key]`` (``count`` of them if given; a missing key is empty)."""
    values = data.get(key) or []
    numbers = [_as_number(v) for v in values] if isinstance(values, list) else [None]
    if None in numbers:
        raise SourceError(f"{where}: {key} must be a list of finite numbers, got {values!r}")
    if count is not None and len(numbers) != count:
        raise SourceError(f"{where}: {key} must hold {count} numbers, got {len(numbers)}")
    return numbers


def _as_number(value) -> float | None:
    """A finite float of a YAML value (a number, or text such as "1e-3"), or None."""
    if isinstance(value, bool) or not isinstance(value, (int, float, str)):
        return None
    try:
        number = float(value)
    except ValueError:
        return None
    return number if math.isfinite(number) else None
