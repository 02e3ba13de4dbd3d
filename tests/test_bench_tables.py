"""The committed benchmark tables under analysis/bench/ are current: made from committed code that
no commit since has changed. The check itself is tested on a small repository in tmp_path."""

from __future__ import annotations

import ast
import importlib
import importlib.util
import json
import subprocess
from pathlib import Path

import pytest

from hingelab.bench import BENCHMARKS, measured_paths
from hingelab.bench.freshness import HistoryUnavailable, require_history, stale_reason
from hingelab.paths import ANALYSIS_DIR, REPO_ROOT

BENCH_DIR = ANALYSIS_DIR / "bench"
NOT_TABLES = {"README.md"}  # the folder's own documentation, if it gets one; history/ is not looked in


# --- the check, on a repository made here ------------------------------------------------------


def _git(root, *args):
    return subprocess.run(["git", "-C", str(root), "-c", "user.name=t", "-c", "user.email=t@t", *args],
                          check=True, capture_output=True, text=True).stdout.strip()


def _commit(root, files: dict[str, str], message: str) -> str:
    for rel, text in files.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(text)
    _git(root, "add", ".")
    _git(root, "commit", "-q", "-m", message)
    return _git(root, "rev-parse", "HEAD")


def _table(root, commit: str, name="fake") -> Path:
    path = root / "analysis" / "bench" / f"{name}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"name": name, "code": {"hingelab_version": "0", "git_commit": commit}}))
    return path


MEASURED = ("platform/hingelab/sim", "assets/scene.xml")
COMMAND = "hingelab bench fake"


@pytest.fixture
def repo(tmp_path):
    """A repository with a measured folder, a measured file and code the bench does not measure."""
    root = tmp_path / "repo"
    root.mkdir()
    _git(root, "init", "-q")
    first = _commit(root, {"platform/hingelab/sim/core.py": "x = 1\n", "assets/scene.xml": "<m/>\n",
                           "platform/hingelab/cli/main.py": "y = 1\n", "README.md": "hi\n"}, "first")
    return root, first


def test_a_table_of_the_head_commit_is_current(repo):
    root, first = repo
    assert stale_reason(_table(root, first), MEASURED, root, COMMAND) is None


def test_commits_that_do_not_touch_the_measured_code_keep_the_table_current(repo):
    root, first = repo
    _commit(root, {"platform/hingelab/cli/main.py": "y = 2\n", "README.md": "changed\n"}, "elsewhere")
    _table(root, first)
    _commit(root, {"analysis/bench/fake.md": "the table\n"}, "the table itself")
    assert stale_reason(root / "analysis/bench/fake.json", MEASURED, root, COMMAND) is None


@pytest.mark.parametrize("changed", ["platform/hingelab/sim/core.py", "platform/hingelab/sim/new.py",
                                     "assets/scene.xml"])
def test_a_commit_that_changes_the_measured_code_makes_it_stale_and_is_named(repo, changed):
    root, first = repo
    second = _commit(root, {changed: "changed\n"}, "change the measured code")
    _commit(root, {"README.md": "later\n"}, "a later commit elsewhere")
    reason = stale_reason(_table(root, first), MEASURED, root, COMMAND)
    assert reason is not None and "\n" not in reason
    assert f"recorded at {first[:12]}" in reason and "in 1 commit (" in reason
    assert second[:7] in reason and f"`{COMMAND}`" in reason


def test_pins_added_to_the_lock_keep_the_table_current_and_a_changed_pin_makes_it_stale(repo):
    root, first = repo
    measured = (*MEASURED, "constraints.txt")
    base = _commit(root, {"constraints.txt": "# header\nnumpy==2.0.0\n"}, "the lock")
    _table(root, base)
    _commit(root, {"constraints.txt": "# header, reworded\nnumpy==2.0.0\nray==2.60.0\n"}, "ray added")
    assert stale_reason(root / "analysis/bench/fake.json", measured, root, COMMAND) is None
    changed = _commit(root, {"constraints.txt": "# header, reworded\nnumpy==2.1.0\nray==2.60.0\n"}, "upgrade")
    reason = stale_reason(root / "analysis/bench/fake.json", measured, root, COMMAND)
    assert reason is not None and "in 1 commit (" in reason and changed[:7] in reason


def test_many_commits_are_counted_and_the_first_few_named(repo):
    root, first = repo
    changes = [_commit(root, {"assets/scene.xml": f"<m{i}/>\n"}, f"change {i}") for i in range(7)]
    reason = stale_reason(_table(root, first), MEASURED, root, COMMAND)
    assert "in 7 commits" in reason and "and 2 more" in reason
    assert changes[-1][:7] in reason and changes[0][:7] not in reason  # newest first


def test_a_table_from_uncommitted_code_is_stale(repo):
    root, first = repo
    reason = stale_reason(_table(root, first + "+dirty.0123456789ab"), MEASURED, root, COMMAND)
    assert "uncommitted" in reason and COMMAND in reason


@pytest.mark.parametrize("recorded", ["unknown", "0" * 40])
def test_a_table_whose_commit_the_repository_does_not_have_is_stale(repo, recorded):
    root, _ = repo
    assert "is not a commit of this repository" in stale_reason(_table(root, recorded), MEASURED, root, COMMAND)


def test_a_table_from_a_commit_outside_the_branch_is_stale(repo):
    root, first = repo
    _git(root, "checkout", "-q", "-b", "side")
    side = _commit(root, {"README.md": "side\n"}, "on a side branch")
    _git(root, "checkout", "-q", "-")
    _commit(root, {"README.md": "main\n"}, "on the main branch")
    assert "not in the history of HEAD" in stale_reason(_table(root, side), MEASURED, root, COMMAND)


def test_a_measured_path_that_does_not_exist_is_an_error_not_a_current_table(repo):
    root, first = repo
    reason = stale_reason(_table(root, first), (*MEASURED, "platform/hingelab/simm"), root, COMMAND)
    assert "platform/hingelab/simm" in reason and "do not exist" in reason


def test_a_table_without_a_code_version_is_stale(repo):
    root, _ = repo
    path = root / "broken.json"
    path.write_text("{}")
    assert "no recorded code version" in stale_reason(path, MEASURED, root, COMMAND)


def test_no_git_history_is_said_plainly(repo, tmp_path):
    elsewhere = tmp_path / "elsewhere"  # tmp_path itself is not inside a git checkout either
    elsewhere.mkdir()
    with pytest.raises(HistoryUnavailable, match="not a git checkout"):
        require_history(elsewhere)
    root, _ = repo
    _commit(root, {"README.md": "two\n"}, "second")
    shallow = tmp_path / "shallow"
    subprocess.run(["git", "clone", "-q", "--depth", "1", f"file://{root}", str(shallow)], check=True,
                   capture_output=True)
    with pytest.raises(HistoryUnavailable, match="shallow clone.*--unshallow"):
        require_history(shallow)
    require_history(root)


# --- the benchmarks' declarations ---------------------------------------------------------------

# not what a benchmark measures: where files go, error types, version strings, the table's format
INFRASTRUCTURE = {"hingelab", "hingelab.paths", "hingelab.errors", "hingelab.provenance"}


def _hingelab_modules_imported_by(path: Path, package: str) -> set[str]:
    """The hingelab modules a source file imports by name, at top level or inside functions."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names if a.name.split(".")[0] == "hingelab")
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package.split(".")[: len(package.split(".")) - node.level + 1] + [base]).strip(".")
            if base.split(".")[0] != "hingelab":
                continue
            found.add(base)
            for alias in node.names:  # `from hingelab.episodes import schemas`: a module too
                if _module_file(f"{base}.{alias.name}") is not None:
                    found.add(f"{base}.{alias.name}")
    return found


def _module_file(name: str) -> Path | None:
    try:
        spec = importlib.util.find_spec(name)
    except ModuleNotFoundError:
        return None
    return Path(spec.origin) if spec is not None and spec.origin else None


@pytest.mark.parametrize("name", list(BENCHMARKS))
def test_each_benchmark_declares_what_it_measures_and_that_covers_what_it_imports(name):
    """MEASURES exist and cover every hingelab module the bench module imports itself (what those
    import in turn is the declaration's judgement: a bench names the parts it measures)."""
    paths = measured_paths(name)
    assert all((REPO_ROOT / p).exists() for p in paths), [p for p in paths if not (REPO_ROOT / p).exists()]
    module_file = Path(importlib.import_module(BENCHMARKS[name]).__file__)
    uncovered = []
    for imported in sorted(_hingelab_modules_imported_by(module_file, "hingelab.bench")):
        if imported in INFRASTRUCTURE or imported.startswith("hingelab.bench"):
            continue
        file = _module_file(imported).resolve().relative_to(REPO_ROOT)
        if not any(file == Path(p) or Path(p) in file.parents for p in paths):
            uncovered.append(f"{imported} ({file})")
    assert not uncovered, f"{BENCHMARKS[name]} imports code its MEASURES do not name: {uncovered}"


def test_every_table_under_analysis_bench_belongs_to_a_benchmark():
    """(That every benchmark has its two tables is checked with their freshness, below.)"""
    orphans = [f"analysis/bench/{p.name}" for p in sorted(BENCH_DIR.iterdir())
               if p.is_file() and p.name not in NOT_TABLES and (p.suffix not in (".md", ".json")
                                                                or p.stem not in BENCHMARKS)]
    assert not orphans, (f"files under analysis/bench/ that no benchmark writes: {orphans}; a kept record "
                         "goes under analysis/bench/history/ with a first line saying what it is")


def test_committed_bench_tables_are_current():
    """Every benchmark has its analysis/bench/NAME.md and NAME.json, and the .json was made at a commit
    after which the code the benchmark measures (hingelab.bench.measured_paths) did not change.

    Without the history (not a git checkout, or a shallow clone) this fails rather than skips: a skip
    would pass silently exactly where nobody looks, and CI runs on a full clone of main, where the
    check can always be made; the message says why and what to do.
    """
    try:
        require_history(REPO_ROOT)
    except HistoryUnavailable as exc:
        pytest.fail(f"cannot check the benchmark tables: {exc}", pytrace=False)
    problems = []
    for name in BENCHMARKS:
        table = BENCH_DIR / f"{name}.json"
        missing = [f"{name}{ext}" for ext in (".md", ".json") if not (BENCH_DIR / f"{name}{ext}").is_file()]
        if missing:
            problems.append(f"analysis/bench/: {' and '.join(missing)} missing; run `hingelab bench {name}`")
            continue
        reason = stale_reason(table, measured_paths(name), REPO_ROOT, f"hingelab bench {name}")
        if reason is not None:
            problems.append(reason.replace(str(REPO_ROOT) + "/", ""))
    if problems:
        pytest.fail(f"{len(problems)} stale benchmark table(s):\n" + "\n".join(problems), pytrace=False)
