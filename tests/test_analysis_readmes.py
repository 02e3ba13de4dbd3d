"""Every file under analysis/ is named, with the command line that made it, in the "Files" section of
its folder's README.md or a parent folder's (analysis/README.md explains the format).

Not checked: README.md files themselves, ``history/`` folders (records made by hand, each with its own
README), ``analysis/bench/`` (its own owner and test) and git-ignored files (``analysis/demo/``).
A "Files" table row counts when its first cell names files in backticks (names or glob patterns
relative to the README's folder; ``name/`` is every file under that folder) and another cell holds a
backticked command line starting with ``hingelab `` or ``python -m hingelab.``.
"""

from __future__ import annotations

import re
import subprocess
from fnmatch import fnmatchcase
from pathlib import Path, PurePosixPath

import pytest

REPO = Path(__file__).resolve().parents[1]
ANALYSIS = REPO / "analysis"
COMMAND = re.compile(r"`(?:hingelab |python -m hingelab\.)[^`]*`")
NAME = re.compile(r"`([^`\s]+)`")
SKIPPED_TOP = {"bench"}


def files_section(text: str) -> list[str]:
    """The lines of the README's "## Files" section (up to the next level-2 heading)."""
    lines, inside = [], False
    for line in text.splitlines():
        if line.startswith("## "):
            inside = line.strip() == "## Files"
            continue
        if inside:
            lines.append(line)
    return lines


def listed_patterns(readme: Path) -> list[str]:
    """The file patterns of the README's Files rows that name a command line."""
    patterns = []
    for line in files_section(readme.read_text()):
        if not line.startswith("|"):
            continue
        cells = re.split(r"(?<!\\)\|", line.strip().strip("|"))
        if len(cells) < 2 or set(cells[0].strip()) <= {"-"}:
            continue
        if any(COMMAND.search(cell) for cell in cells[1:]):
            patterns += NAME.findall(cells[0])
    return patterns


def matches(pattern: str, rel: PurePosixPath) -> bool:
    parts = pattern.rstrip("/").split("/")
    if pattern.endswith("/"):  # a folder: every file under it
        return len(rel.parts) > len(parts) and all(fnmatchcase(r, p) for r, p in zip(rel.parts, parts))
    return len(rel.parts) == len(parts) and all(fnmatchcase(r, p) for r, p in zip(rel.parts, parts))


def checked(rel: PurePosixPath) -> bool:
    """``rel``: a path relative to the analysis folder."""
    return rel.name != "README.md" and "history" not in rel.parts[:-1] and rel.parts[0] not in SKIPPED_TOP


def unlisted(analysis: Path, files) -> list[str]:
    """The files (relative to ``analysis``) that no README of their folder or a parent folder lists."""
    cache: dict[Path, list[str]] = {}
    missing = []
    for rel in files:
        rel = PurePosixPath(rel)
        if not checked(rel):
            continue
        found = False
        for depth in range(len(rel.parts) - 1, -1, -1):
            folder = analysis.joinpath(*rel.parts[:depth])
            readme = folder / "README.md"
            if readme not in cache:
                cache[readme] = listed_patterns(readme) if readme.exists() else []
            inner = PurePosixPath(*rel.parts[depth:])
            if any(matches(p, inner) for p in cache[readme]):
                found = True
                break
        if not found:
            missing.append(str(rel))
    return missing


def analysis_files() -> list[str]:
    """Committed and new (not git-ignored) files under analysis/, relative to it."""
    try:
        out = subprocess.run(["git", "-C", str(REPO), "ls-files", "--cached", "--others", "--exclude-standard",
                              "-z", "--", "analysis"], capture_output=True, check=True, timeout=30).stdout
    except (OSError, subprocess.SubprocessError):
        pytest.skip("not a git checkout: cannot tell committed results from ignored outputs")
    paths = [p for p in out.decode().split("\0") if p]
    return sorted({str(PurePosixPath(p).relative_to("analysis")) for p in paths if (REPO / p).is_file()})


def test_every_result_file_is_listed_with_its_command():
    files = analysis_files()
    assert files, "no files under analysis/"
    missing = unlisted(ANALYSIS, files)
    assert not missing, ("files under analysis/ that no README lists with the command that made them (add a "
                         "row to the folder README's Files table, or move a hand-made record to history/): "
                         + ", ".join(missing))


def test_listed_names_exist():
    """A README that names a file (no glob, not a folder) names one that is there: no stale rows."""
    stale = []
    for readme in sorted(ANALYSIS.rglob("README.md")):
        rel = readme.relative_to(ANALYSIS)
        if rel.parts[0] in SKIPPED_TOP or "history" in rel.parts:
            continue
        for pattern in listed_patterns(readme):
            if pattern.endswith("/") or any(c in pattern for c in "*?["):
                continue
            if not (readme.parent / pattern).exists():
                stale.append(f"{rel}: {pattern}")
    assert not stale, "README rows name files that do not exist: " + ", ".join(stale)


def test_every_analysis_folder_has_a_readme():
    folders = {PurePosixPath(f).parts[0] for f in analysis_files() if len(PurePosixPath(f).parts) > 1}
    assert (ANALYSIS / "README.md").exists()
    missing = sorted(f for f in folders - SKIPPED_TOP if not (ANALYSIS / f / "README.md").exists())
    assert not missing, f"analysis folders without a README.md: {missing}"
    for history in ANALYSIS.rglob("history"):
        if history.is_dir() and history.relative_to(ANALYSIS).parts[0] not in SKIPPED_TOP:
            assert (history / "README.md").exists(), f"{history} has no README.md saying what its records are"


def test_the_check_fails_on_a_new_unlisted_file(tmp_path):
    analysis = tmp_path / "analysis"
    (analysis / "study" / "history").mkdir(parents=True)
    (analysis / "README.md").write_text("# index\n\n## Files\n\n| file | made by |\n|---|---|\n"
                                        "| `study/pooled/` | "
                                        "`hingelab report --pool a b --out analysis/study/pooled` |\n")
    (analysis / "study" / "README.md").write_text(
        "# study\n\n| file | made by |\n|---|---|\n| `outside.csv` | `hingelab report x --out y` |\n\n"
        "## Files\n\n| file | what | made by |\n|---|---|---|\n"
        "| `report.md`, `seed*/episodes.csv` | the evaluation | `hingelab eval low --seed S --out DIR`, copied |\n"
        "| `notes.csv` | typed by hand | by hand |\n\n## Result\n\n| `late.csv` | `hingelab report z` |\n")
    files = ["README.md", "study/README.md", "study/report.md", "study/seed3/episodes.csv",
             "study/pooled/pooled.md", "study/history/old.md", "bench/sim.md"]
    assert unlisted(analysis, files) == []
    new = ["study/new.csv", "study/notes.csv", "study/outside.csv", "study/late.csv", "study/seed3/regions.csv",
           "other/x.png"]
    assert unlisted(analysis, files + new) == new
