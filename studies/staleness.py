"""When result rows were made and whether the code they measure has changed since: stamps from the rows or from
git, and the commits after them that touched the measured paths (``studies.results`` renders both).

A row's stamp is its own ``made_at`` (``{"commit", "date"}``, written by ``openmulti reproduce`` since issue 61)
or, for rows made before, the last commit that changed its rows file: the per-run row file of ``openmulti
reproduce`` that holds the same row, the line of a ``.jsonl`` rows file (``git blame``), else the whole file. Rows
are stale when a commit after any of their stamps, up to HEAD, touched a measured path, unless
``docs/results_neutral_commits.txt`` lists that commit as leaving results unchanged. Only committed history counts
(HEAD, not the working tree), so the answer is the same on every clone of a commit; a commit that changes measured
code makes the generated pages out of date until ``python -m studies.results --write`` runs again. Without git
(an unpacked sdist) a row without ``made_at`` has an unknown stamp and nothing is called stale or fresh.
"""

from __future__ import annotations

import json
import re
import subprocess
from dataclasses import dataclass, field
from pathlib import Path

HASH = re.compile(r"[0-9a-f]{40}")
LOG_FORMAT = "--format=%H%x1f%ct%x1f%cs%x1f%s"
NOT_CODE = (":(exclude)*.md",)
"""Files under a measured path that change no result: a commit touching only these is not counted."""


@dataclass(frozen=True)
class Stamp:
    """When a row was made: a commit of this repository (full hash) and its date; ``commit`` None when unknown,
    with ``note`` saying why (or what the row named instead, e.g. a package version)."""

    commit: str | None
    date: str | None
    note: str = ""


@dataclass(frozen=True)
class RowsStamp:
    """A rows file (path relative to the repository), how many rows it has and their distinct stamps, oldest
    first (unknown ones before the known)."""

    path: str
    rows: int
    stamps: tuple[Stamp, ...]


@dataclass(frozen=True)
class Commit:
    """One commit of the history: full hash, committer time (Unix) and date, subject line."""

    hash: str
    time: int
    date: str
    subject: str


@dataclass(frozen=True)
class Staleness:
    """The commits after a set of stamps that touched the measured paths (oldest first, neutral ones left out);
    ``known`` False when that cannot be told (no git, or a stamp outside this history), ``reason`` saying why."""

    known: bool
    commits: tuple[Commit, ...] = ()
    reason: str = ""

    @property
    def stale(self) -> bool:
        return self.known and bool(self.commits)


def parse_log(out: str) -> list[Commit]:
    """Commits from ``git log`` with ``LOG_FORMAT``, in its order."""
    found = []
    for line in out.splitlines():
        if line.strip():
            commit, time, date, subject = line.split("\x1f", 3)
            found.append(Commit(commit, int(time), date, subject))
    return found


@dataclass
class Git:
    """``git`` in the repository at ``root`` (``available`` False without ``root/.git`` or a ``git`` binary)."""

    root: Path
    _available: bool | None = None
    _commits: dict[str, Commit | None] = field(default_factory=dict)
    _after: dict[tuple[str, tuple[str, ...]], tuple[Commit, ...]] = field(default_factory=dict)

    @property
    def available(self) -> bool:
        if self._available is None:
            self._available = (self.root / ".git").exists() and self.run("rev-parse", "HEAD") is not None
        return self._available

    def run(self, *args: str) -> str | None:
        """stdout of ``git -C root ARGS`` (None when git is missing or fails)."""
        try:
            done = subprocess.run(["git", "-C", str(self.root), "-c", "core.quotepath=off", *args],
                                  capture_output=True, text=True, timeout=120, check=False)
        except (OSError, subprocess.SubprocessError):
            return None
        return done.stdout if done.returncode == 0 else None

    def commit(self, ref: str) -> Commit | None:
        """The commit ``ref`` names, if this history has it."""
        if ref not in self._commits:
            out = self.run("log", "-1", LOG_FORMAT, ref + "^{commit}", "--")
            self._commits[ref] = parse_log(out)[0] if out else None
        return self._commits[ref]

    def last_changes(self, paths: list[str]) -> dict[str, Stamp]:
        """For each path (relative to root), the last commit up to HEAD that changed it (one ``git log`` a batch)."""
        found: dict[str, Stamp] = {}
        wanted = set(paths)
        for start in range(0, len(paths), 200):  # keeps the command line short
            out = self.run("log", "--format=%x1e%H%x1f%cs", "--name-only", "HEAD", "--", *paths[start:start + 200])
            for block in (out or "").split("\x1e")[1:]:
                head, *names = block.strip("\n").split("\n")
                commit, date = head.split("\x1f")
                for name in names:
                    if name in wanted and name not in found:
                        found[name] = Stamp(commit, date)
        return found

    def blame(self, path: str) -> list[Stamp | None]:
        """The commit that added each line of ``path`` (``git blame``; a line not committed yet has an unknown
        stamp; empty when the file is not in the history at all)."""
        out = self.run("blame", "--porcelain", "--", path)
        if out is None:
            return []
        stamps: list[Stamp | None] = []
        commit = None
        for line in out.splitlines():
            if HASH.fullmatch(line[:40]) and line[40:41] == " ":
                commit = line[:40]
            elif line.startswith("\t"):
                found = self.commit(commit) if commit and commit.strip("0") else None
                stamps.append(Stamp(found.hash, found.date) if found else Stamp(None, None, "not committed yet"))
        return stamps

    def commits_after(self, commit: str, paths: tuple[str, ...]) -> tuple[Commit, ...]:
        """Commits in ``commit..HEAD`` that touched ``paths`` (their documentation aside), newest first."""
        key = (commit, paths)
        if key not in self._after:
            out = self.run("log", LOG_FORMAT, f"{commit}..HEAD", "--", *paths, *NOT_CODE)
            self._after[key] = tuple(parse_log(out or ""))
        return self._after[key]


def read_neutral(path: Path) -> dict[str, str]:
    """``docs/results_neutral_commits.txt``: one ``<full hash> <reason>`` a line (``#`` comments and blank lines
    skipped); ValueError naming a line that is not so."""
    if not path.is_file():
        return {}
    neutral = {}
    for number, line in enumerate(path.read_text().splitlines(), 1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        commit, _, reason = text.partition(" ")
        if not HASH.fullmatch(commit) or not reason.strip():
            raise ValueError(f"{path}:{number}: expected '<40-hex commit> <reason>', got {text[:60]!r}")
        neutral[commit] = reason.strip()
    return neutral


def row_stamp(row: dict) -> Stamp | None:
    """A row's own ``made_at`` (None when it has none); one naming no commit (an installed package's version) is a
    stamp with an unknown commit."""
    made = row.get("made_at")
    if not isinstance(made, dict):
        return None
    return made_stamp(str(made.get("commit", "")), made.get("date"))


def made_stamp(commit: str, date: str | None) -> Stamp:
    """The stamp of a ``made_at`` naming ``commit`` (a full hash, else what made the row, e.g. a version)."""
    if HASH.fullmatch(commit):
        return Stamp(commit, date)
    return Stamp(None, date, f"made by {commit or 'unknown code'}")


def stamp_rows(git: Git, path: str, rows: list[dict], fallback: list[Stamp | None] | None = None) -> RowsStamp:
    """``rows`` of the rows file ``path`` (relative to the repository) stamped by their ``made_at``, else by
    ``fallback`` (one per row), else by the file's last change. Without git only ``made_at`` stamps are known."""
    fallback = fallback or [None] * len(rows)
    whole: Stamp | None = None
    stamps = []
    for row, other in zip(rows, fallback):
        stamp = row_stamp(row) or other
        if stamp is None and not git.available:
            stamp = Stamp(None, None, "no git history here")
        elif stamp is None:
            whole = whole or git.last_changes([path]).get(path) or Stamp(None, None, "not committed yet")
            stamp = whole
        stamps.append(stamp)
    distinct = list({(s.commit, s.date, s.note): s for s in stamps}.values())
    distinct.sort(key=lambda s: (s.commit is not None, s.date or "", commit_time(git, s.commit)))
    return RowsStamp(path, len(rows), tuple(distinct))


def commit_time(git: Git, commit: str | None) -> int:
    """The committer time of ``commit`` (0 when unknown or without git)."""
    found = git.commit(commit) if commit and git.available else None
    return found.time if found else 0


def staleness(git: Git, stamps: list[RowsStamp], paths: tuple[str, ...], neutral: dict[str, str]) -> Staleness:
    """The commits after any of ``stamps`` that touched ``paths``, the neutral ones aside."""
    if not git.available:
        return Staleness(False, reason="no git history here")
    unknown = [s.note for rows in stamps for s in rows.stamps if s.commit is None]
    if unknown:
        return Staleness(False, reason=unknown[0])
    outside = [s.commit for rows in stamps for s in rows.stamps if s.commit and git.commit(s.commit) is None]
    if outside:
        return Staleness(False, reason=f"commit {outside[0][:7]} is not in this history")
    after: dict[str, Commit] = {}
    for rows in stamps:
        for stamp in rows.stamps:
            for found in git.commits_after(str(stamp.commit), paths):
                if found.hash not in neutral:
                    after[found.hash] = found
    return Staleness(True, tuple(sorted(after.values(), key=lambda c: c.time)))


def reproduce_fallback(git: Git, root: Path, table_file: str, rows: list[dict]) -> list[Stamp | None]:
    """For each row of an ``openmulti reproduce`` table file, the last change of the per-run row file beside it
    (``DIR/rows/<key>.json`` holding the same row), or None when there is none."""
    folder = root / Path(table_file).parent / "rows"
    files: dict[str, str] = {}
    for path in sorted(folder.glob("*.json")) if folder.is_dir() else []:
        try:
            files[identity(json.loads(path.read_text()).get("row", {}))] = str(path.relative_to(root))
        except (OSError, ValueError, AttributeError):
            continue
    changes = git.last_changes(sorted(set(files.values()))) if git.available and files else {}
    return [changes.get(files.get(identity(row), "")) for row in rows]


def identity(row: dict) -> str:
    """A row as text, for finding the same row in another file."""
    return json.dumps(row, sort_keys=True)


def jsonl_rows(git: Git, root: Path, path: str) -> tuple[list[dict], list[Stamp | None]]:
    """The rows of the ``.jsonl`` file ``path`` (blank lines skipped) and, for each, the commit that added its line
    (None when the file is not in the history)."""
    lines = (root / path).read_text().splitlines()
    blamed = git.blame(path) if git.available else []
    blamed = blamed if len(blamed) == len(lines) else [None] * len(lines)
    kept = [(json.loads(line), stamp) for line, stamp in zip(lines, blamed) if line.strip()]
    return [row for row, _ in kept], [stamp for _, stamp in kept]
