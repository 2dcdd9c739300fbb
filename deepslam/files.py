"""Writing files without losing data: an output is checked against the inputs it is made from (under any
name, hard links and symlinks included), written as ``OUT.partial`` and renamed over ``OUT`` only when
it is whole, so that a failed or refused write leaves ``OUT`` as it was."""

from __future__ import annotations

import os
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from deepslam.errors import InputError


class OutputError(InputError):
    """An output path that cannot be written as asked."""


def partial_path(path: str | Path) -> Path:
    """Where a file bound for ``path`` is written until it is whole."""
    path = Path(path)
    return path.with_name(path.name + ".partial")


def check_output(path: str | Path, inputs: tuple[str | Path, ...] = ()) -> None:
    """Raise ``OutputError`` unless a file can be written to ``path``: not a folder, nor a device, a pipe or a
    socket (the finished ``.partial`` is renamed onto ``path``, which would replace such a file: ``/dev/null``
    itself, for root), its folder writable (or creatable), and neither ``path`` nor its ``.partial`` the same
    file as any of ``inputs`` under any name (hard links and symlinks included)."""
    path = Path(path)
    if path.is_dir():
        raise OutputError(f"{path} is a folder; give a file name")
    if path.exists() and not path.is_file():
        raise OutputError(f"{path} is not a regular file (a device, a pipe or a socket); give a file name")
    for target in (path, partial_path(path)):
        for source in inputs:
            if target.exists() and Path(source).exists() and target.samefile(source):
                raise OutputError(f"writing {target} would overwrite the input {source}; choose another output")
    folder = path.parent
    while not folder.exists():
        folder = folder.parent
    if not folder.is_dir() or not os.access(folder, os.W_OK | os.X_OK):
        raise OutputError(f"cannot write {path.name} under {folder}: not a writable folder")


@contextmanager
def written(path: str | Path, inputs: tuple[str | Path, ...] = ()) -> Iterator[Path]:
    """Write ``path`` by way of its ``.partial`` (checked first, ``check_output``): the block writes the
    yielded path; it becomes ``path`` when the block ends normally and is removed when it raises, so that
    ``path`` keeps what it held. An ``OSError`` (a full disk) names the file."""
    check_output(path, inputs)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = partial_path(path)
    try:
        yield partial
    except OSError as error:
        partial.unlink(missing_ok=True)
        raise OSError(error.errno, error.strerror or str(error), str(error.filename or partial)) from None
    except BaseException:
        partial.unlink(missing_ok=True)
        raise
    partial.replace(path)


def distinct_names(paths: list[str | Path]) -> dict[str, str]:
    """A name for each of ``paths`` (by ``str(path)``) to show it by: its file name, or where files of the same name
    come from different folders, as many of its last folders as tell them apart (``a/run.mcap``, ``b/run.mcap``).

    Example:
        >>> distinct_names(["out/a/run.mcap", "out/b/run.mcap", "lk.mcap"])
        {'out/a/run.mcap': 'a/run.mcap', 'out/b/run.mcap': 'b/run.mcap', 'lk.mcap': 'lk.mcap'}
    """
    parts = {str(path): Path(path).parts for path in paths}
    names = {}
    for key, own in parts.items():
        kin = [other for other in set(parts.values()) if other != own and other[-1:] == own[-1:]]
        depth = 1
        while depth < len(own) and any(other[-depth:] == own[-depth:] for other in kin):
            depth += 1
        names[key] = str(Path(*own[-depth:]))
    return names
