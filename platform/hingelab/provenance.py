"""Where an artifact came from: code version, git commit, machine.

Every dataset card, checkpoint, report and benchmark table records these so that a
result can be traced back to the code that made it.

"Dirty" means the code or the models differ from the commit: tracked changes or
untracked files under ``CODE_PATHS``. Results, datasets and run folders elsewhere in the
checkout do not count, so writing a report does not make the next one dirty. A dirty
version names a hash of the difference (``<commit>+dirty.<12 hex>``), so two artifacts
made from the same uncommitted code can be told to be alike.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import platform as _stdlib_platform  # the standard module, not our source root
import subprocess
from pathlib import Path

from hingelab import __version__
from hingelab.errors import ConfigError
from hingelab.paths import ANALYSIS_DIR, REPO_ROOT

# what makes a result: the package, the models and checkpoints, the declared dependencies
CODE_PATHS = ("platform", "assets", "pyproject.toml")


def _git(*args: str) -> str:
    return subprocess.run(["git", "-C", str(REPO_ROOT), *args], capture_output=True, text=True,
                          timeout=10, check=True).stdout


def _dirty_changes() -> tuple[list[str], str]:
    """(changed paths under CODE_PATHS, sha256 of their diff and untracked contents); ([], "") if clean."""
    status = _git("status", "--porcelain", "--untracked-files=all", "--", *CODE_PATHS)
    changed = [line[3:] for line in status.splitlines() if line.strip()]
    if not changed:
        return [], ""
    digest = hashlib.sha256(_git("diff", "HEAD", "--binary", "--", *CODE_PATHS).encode())
    for line in status.splitlines():
        if line.startswith("??"):
            path = REPO_ROOT / line[3:]
            digest.update(line[3:].encode())
            if path.is_file():
                digest.update(path.read_bytes())
    return changed, digest.hexdigest()[:12]


@functools.cache
def git_commit() -> str:
    """The checkout's commit hash, with '+dirty.<hash of the diff>' if the code or models changed.

    'unknown' outside a git checkout (an installed wheel). Cached: the version as the
    process started, so files a command writes while it runs cannot change it.
    """
    try:
        commit = _git("rev-parse", "HEAD").strip()
        changed, digest = _dirty_changes()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return commit + (f"+dirty.{digest}" if changed else "")


def is_dirty(version: str | None = None) -> bool:
    return "+dirty" in (version if version is not None else git_commit())


def dirty_files() -> list[str]:
    try:
        return _dirty_changes()[0]
    except (OSError, subprocess.SubprocessError):
        return []


def require_clean_for(out: Path, allow_dirty: bool, command: str) -> None:
    """Refuse to write committed results (under analysis/) from code that differs from its commit.

    Raises ConfigError naming the changed files and the two ways out (commit, or
    ``--allow-dirty`` for a result that is knowingly not reproducible from a commit).
    """
    out = Path(out).resolve()
    if allow_dirty or not out.is_relative_to(ANALYSIS_DIR.resolve()) or _ignored(out) or not is_dirty():
        return
    files = dirty_files()
    shown = ", ".join(files[:5]) + (f" and {len(files) - 5} more" if len(files) > 5 else "")
    raise ConfigError(f"{command} would write {out} under analysis/ from uncommitted code ({shown}): "
                      "commit first so the result names the code that made it, write elsewhere with "
                      "--out, or pass --allow-dirty")


def _ignored(path: Path) -> bool:
    """A git-ignored output folder (analysis/demo/) is not a committed result."""
    try:  # a file inside it: a pattern with a trailing slash matches only a folder that exists
        return subprocess.run(["git", "-C", str(REPO_ROOT), "check-ignore", "-q", str(path / "_")],
                              capture_output=True, timeout=10).returncode == 0
    except (OSError, subprocess.SubprocessError):
        return False


def code_version() -> dict[str, str]:
    """hingelab version and git commit, for dataset cards and checkpoints."""
    return {"hingelab_version": __version__, "git_commit": git_commit()}


def machine() -> dict[str, str]:
    """What ran a benchmark: CPU, core count, Python."""
    return {
        "processor": _stdlib_platform.processor() or _stdlib_platform.machine(),
        "cores": str(os.cpu_count()),
        "python": _stdlib_platform.python_version(),
        "system": _stdlib_platform.platform(),
    }


def differing_settings(recorded: dict | None, wanted: dict, ignore=()) -> dict:
    """{setting: (recorded, wanted)} where a run's recorded config (a dataset card's, JSON) and the one asked
    for now differ, compared as JSON (tuples as lists), ``ignore`` left out: what a ``--resume`` refuses."""
    def plain(config):
        return {k: v for k, v in json.loads(json.dumps(config or {}, default=str)).items() if k not in ignore}

    recorded, wanted = plain(recorded), plain(wanted)
    return {k: (recorded.get(k), wanted.get(k)) for k in sorted(set(recorded) | set(wanted))
            if recorded.get(k) != wanted.get(k)}
