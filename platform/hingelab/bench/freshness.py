"""Is a committed benchmark table older than the code it measures?

A table (``analysis/bench/NAME.json``) records the commit of the code that made it. It is
current when that is a plain commit (not ``+dirty``) of this branch's history and no commit
since has changed the paths the benchmark measures (``hingelab.bench.measured_paths``).
Uncommitted changes do not count here: a table can only be made from committed code, so a
change makes the table stale once it is committed.
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

MAX_COMMITS_NAMED = 5


class HistoryUnavailable(Exception):
    """The checkout cannot answer (not a git repository, no git, a shallow clone)."""


def _git(repo: Path, *args: str, check: bool = True) -> subprocess.CompletedProcess:
    return subprocess.run(["git", "-C", str(repo), *args], capture_output=True, text=True, timeout=60, check=check)


def require_history(repo: Path) -> None:
    """Raise ``HistoryUnavailable`` saying why, unless ``repo`` is a full git clone."""
    try:
        inside = _git(repo, "rev-parse", "--is-inside-work-tree", check=False)
    except OSError as exc:
        raise HistoryUnavailable(f"git cannot be run ({exc}): the tables' recorded commits cannot be "
                                 "compared with the history") from None
    if inside.returncode != 0 or inside.stdout.strip() != "true":
        raise HistoryUnavailable(f"{repo} is not a git checkout: the tables' recorded commits cannot be compared "
                                 "with the history; run this in a clone of the repository")
    if _git(repo, "rev-parse", "--is-shallow-repository").stdout.strip() == "true":
        raise HistoryUnavailable(f"{repo} is a shallow clone: the commits the tables record may be missing from "
                                 "it; `git fetch --unshallow` first")


def stale_reason(json_path: Path, measured: tuple[str, ...], repo: Path, command: str) -> str | None:
    """One line saying why the table at ``json_path`` is stale, or None if it is current.

    ``measured``: repository paths (files or folders) the benchmark measures; ``command``: what
    regenerates the table. ``repo`` must pass ``require_history``.
    """
    try:
        table = json.loads(Path(json_path).read_text())
        recorded = str(table["code"]["git_commit"])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        return f"{json_path}: no recorded code version ({type(exc).__name__}: {exc}); run `{command}`"
    where = f"{json_path} (recorded at {recorded[:12]}{'+dirty' if '+dirty' in recorded else ''})"
    if "+dirty" in recorded:
        return (f"{where}: made from uncommitted changes, so no commit has its code; run `{command}` from "
                "committed code")
    if _git(repo, "cat-file", "-e", f"{recorded}^{{commit}}", check=False).returncode != 0:
        return f"{where}: {recorded!r} is not a commit of this repository; run `{command}`"
    if _git(repo, "merge-base", "--is-ancestor", recorded, "HEAD", check=False).returncode != 0:
        return f"{where}: {recorded[:12]} is not in the history of HEAD (rebased away?); run `{command}`"
    missing = [p for p in measured if not (Path(repo) / p).exists()]
    if missing:  # a renamed or mistyped path would otherwise never make the table stale
        return f"{where}: the measured paths {missing} do not exist; fix the benchmark's MEASURES"
    log = _git(repo, "log", "--format=%h", f"{recorded}..HEAD", "--", *measured).stdout.split()
    if not log:
        return None
    named = ", ".join(log[:MAX_COMMITS_NAMED]) + (f" and {len(log) - MAX_COMMITS_NAMED} more"
                                                   if len(log) > MAX_COMMITS_NAMED else "")
    return (f"{where}: the code it measures changed since in {len(log)} commit{'s' * (len(log) > 1)} "
            f"({named}); run `{command}`")
