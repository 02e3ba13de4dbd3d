"""Where an artifact came from: code version, git commit, machine.

Every dataset card, checkpoint and benchmark table records these so that a
result can be traced back to the code that made it.
"""

from __future__ import annotations

import functools
import platform as _stdlib_platform  # the standard module, not our source root
import subprocess

from hingelab import __version__
from hingelab.paths import REPO_ROOT


@functools.cache
def git_commit() -> str:
    """The checkout's commit hash, with '+dirty' if it has uncommitted changes.

    'unknown' outside a git checkout (an installed wheel).
    """
    try:
        commit = subprocess.run(
            ["git", "-C", str(REPO_ROOT), "rev-parse", "HEAD"],
            capture_output=True, text=True, timeout=5, check=True,
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "-C", str(REPO_ROOT), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True, text=True, timeout=5, check=True,
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return commit + ("+dirty" if dirty else "")


def code_version() -> dict[str, str]:
    """hingelab version and git commit, for dataset cards and checkpoints."""
    return {"hingelab_version": __version__, "git_commit": git_commit()}


def machine() -> dict[str, str]:
    """What ran a benchmark: CPU, core count, Python."""
    import os

    return {
        "processor": _stdlib_platform.processor() or _stdlib_platform.machine(),
        "cores": str(os.cpu_count()),
        "python": _stdlib_platform.python_version(),
        "system": _stdlib_platform.platform(),
    }

