"""A study's rows file: one JSON object a line, appended as each episode or run ends.

Appending row by row lets a long study stop anywhere and resume: a rerun reads what is there and plays
only what is missing.
"""

from __future__ import annotations

import json
from pathlib import Path


def read_rows(path: Path) -> list[dict]:
    """Every row of ``path`` in file order (none when the file does not exist yet; blank lines skipped)."""
    path = Path(path)
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def append_row(path: Path, row: dict) -> None:
    """One finished row, appended at once (the folder made when missing)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("a") as f:
        f.write(json.dumps(row) + "\n")
