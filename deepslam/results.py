"""What an evaluation or a benchmark returns: its figures, as a table and as files.

Every result is a dataclass whose fields are its figures. ``table()`` gives the text the command prints;
``save(out)`` writes ``NAME.txt``, ``NAME.json`` (``to_dict()``) and its plots into the folder ``out``.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path


class Result:
    """Base of the results; a subclass sets ``name`` (its files' stem) and ``lines()``, and may add ``plots``."""

    name: str

    def to_dict(self) -> dict:
        """The figures as plain data (what ``NAME.json`` holds)."""
        return dataclasses.asdict(self)

    def lines(self) -> list[str]:
        raise NotImplementedError

    def table(self) -> str:
        """The figures as the command prints them."""
        return "\n".join(self.lines())

    def plots(self, out: Path) -> list[Path]:
        """PNG plots written into the existing folder ``out``; none by default."""
        return []

    def save(self, out: str | Path) -> list[Path]:
        """Write the plots, ``NAME.txt`` and ``NAME.json`` into ``out`` (made if missing); their paths."""
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        text, data = out / f"{self.name}.txt", out / f"{self.name}.json"
        plots = self.plots(out)
        text.write_text(self.table() + "\n")
        data.write_text(json.dumps(self.to_dict(), indent=1))
        return [*plots, text, data]
