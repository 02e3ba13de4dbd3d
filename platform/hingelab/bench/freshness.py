"""Is a committed benchmark table older than the code it measures?

A table (``analysis/bench/NAME.json``, or in the benchmark's own folder: ``hingelab.bench.table_dir``)
records the commit of the code that made it. It is current when that is a plain commit (not
``+dirty``) of this branch's history and no commit since has changed the paths the benchmark
measures (``hingelab.bench.measured_paths``).
Uncommitted changes do not count here: a table can only be made from committed code, so a
change makes the table stale once it is committed.

The lock file (``constraints.txt``, measured by every benchmark) is compared pin by pin: a commit
that only adds pins (a new package for code the benchmark does not run, e.g. Ray for the sweeps)
leaves every package the table was measured with as it was, so it does not make the table stale;
a commit that changes or removes a pin does.

``hingelab bench --stale`` prints ``report``: a stale table is something to regenerate, not an
error, so neither that command nor the default test run fails on one.
"""

from __future__ import annotations

import json
import subprocess
from collections.abc import Callable, Iterable
from pathlib import Path

from hingelab.bench import measured_paths as bench_measured_paths

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
    regenerates the table. ``repo`` must pass ``require_history``. A stale table's line names the
    oldest commit that changed what it measures ("stale since") and the newest few, newest first.
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
    log = [commit for commit in log if _changes_what_it_measures(repo, commit, measured)]
    if not log:
        return None
    named = ", ".join(log[:MAX_COMMITS_NAMED]) + (f" and {len(log) - MAX_COMMITS_NAMED} more"
                                                   if len(log) > MAX_COMMITS_NAMED else "")
    return (f"{where}: stale since {log[-1]}, the code it measures changed in {len(log)} "
            f"commit{'s' * (len(log) > 1)} ({named}); run `{command}`")


LOCK_FILE = "constraints.txt"


def _changes_what_it_measures(repo: Path, commit: str, measured: tuple[str, ...]) -> bool:
    """Whether ``commit`` changes a measured path other than by adding pins to the lock file."""
    others = [p for p in measured if p != LOCK_FILE]
    if others and _git(repo, "diff", "--name-only", f"{commit}^", commit, "--", *others,
                       check=False).stdout.strip():
        return True
    if LOCK_FILE not in measured:
        return False
    diff = _git(repo, "diff", "--unified=0", f"{commit}^", commit, "--", LOCK_FILE, check=False)
    if diff.returncode != 0:
        return True  # a root commit or an unreadable diff: count it
    removed = [line[1:] for line in diff.stdout.splitlines() if line.startswith("-") and not line.startswith("---")]
    return any(line.split("#")[0].strip() for line in removed)  # a pin changed or went (headers do not count)


def report(repo: Path, bench_dir: Path, names: Iterable[str],
           measured_paths: Callable[[str], tuple[str, ...]] | None = None,
           table_dir: Callable[[str], Path] | None = None) -> list[tuple[str, bool]]:
    """One ``(line, stale)`` per benchmark in ``names``: its table under ``bench_dir`` (or the folder
    ``table_dir(name)`` gives), current or why not.

    A stale line names the table, the commit it records, the commits since that changed what it
    measures and the command that regenerates it (``hingelab bench NAME``); a missing table is stale.
    Paths are shown relative to ``repo``. ``measured_paths``: name -> the paths that benchmark
    measures (default ``hingelab.bench.measured_paths``). Raises ``HistoryUnavailable`` when ``repo``
    cannot answer.
    """
    measured_paths = measured_paths or bench_measured_paths
    require_history(repo)
    repo, bench_dir = Path(repo), Path(bench_dir)

    def shown(path: Path) -> str:
        try:
            return path.resolve().relative_to(repo.resolve()).as_posix()
        except ValueError:
            return str(path)

    lines = []
    for name in names:
        command = f"hingelab bench {name}"
        folder = Path(table_dir(name)) if table_dir is not None else bench_dir
        json_path = folder / f"{name}.json"
        missing = [f"{name}{ext}" for ext in (".md", ".json") if not (folder / f"{name}{ext}").is_file()]
        if missing:
            lines.append((f"{shown(json_path)}: {' and '.join(missing)} missing; run `{command}`", True))
            continue
        try:
            measured = measured_paths(name)
        except ImportError as exc:  # a broken benchmark module: say so for its table, report the others
            lines.append((f"{shown(json_path)}: cannot tell what it measures, its module does not import "
                          f"({type(exc).__name__}: {exc})", True))
            continue
        reason = stale_reason(json_path, measured, repo, command)
        if reason is None:
            recorded = str(json.loads(json_path.read_text())["code"]["git_commit"])
            lines.append((f"{shown(json_path)} (recorded at {recorded[:12]}): current", False))
        else:
            lines.append((reason.replace(str(json_path), shown(json_path), 1), True))
    return lines
