"""When a result was made: the commit of the code that made it and the UTC date, written into result rows as
``made_at`` so that the pages quoting them can tell how old they are (``python -m studies.results`` marks a row
stale when a later commit changed the code it measures).

The commit is ``git rev-parse HEAD`` of the checkout the package runs from; an installed package (no ``.git``
beside it) gives its version instead (``openmulti 0.1.0``), which no page can place in the history: such rows are
shown with an unknown stamp rather than a wrong one. ``made_at`` never enters a row's settings, so a row made
before it existed is reused as before.
"""

from __future__ import annotations

import subprocess
from datetime import datetime, timezone
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
"""The checkout's root when the package runs from one (``ROOT/.git`` exists)."""


def made_at(root: Path = ROOT) -> dict[str, str]:
    """``{"commit": ..., "date": "YYYY-MM-DD"}`` for a row made now by the code under ``root``."""
    return {"commit": code_commit(root), "date": datetime.now(timezone.utc).date().isoformat()}


def code_commit(root: Path = ROOT) -> str:
    """The full hash of ``root``'s checked-out commit, or ``openmulti VERSION`` outside a git checkout."""
    if (root / ".git").exists():
        try:
            done = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True,
                                  timeout=30, check=False)
        except (OSError, subprocess.SubprocessError):
            done = None
        commit = done.stdout.strip() if done is not None and done.returncode == 0 else ""
        if len(commit) == 40:
            return commit
    return f"openmulti {package_version()}"


def package_version() -> str:
    """The installed distribution's version (``unknown`` when the package is not installed)."""
    from importlib.metadata import PackageNotFoundError, version  # noqa: PLC0415

    try:
        return version("openmulti")
    except PackageNotFoundError:
        return "unknown"
