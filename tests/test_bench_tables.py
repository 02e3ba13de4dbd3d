"""The benchmark tables under analysis/bench/ and the check of their freshness.

A stale table is not a failure of the test run: a commit that changes code a benchmark measures makes
its table stale until someone re-runs the benchmark, and ``hingelab bench --stale`` (printed by .ci/run)
says which tables, since which commit and the command to regenerate each. Tested here: the check itself,
on small repositories in tmp_path; that ``hingelab bench --stale`` reports on this repository; what each
benchmark declares it measures; and the tables' format (both files, the code version they record)."""

from __future__ import annotations

import ast
import importlib
import importlib.util
import json
import subprocess
from pathlib import Path

import pytest

from hingelab.bench import BENCHMARKS, measured_paths, table_dir
from hingelab.bench.freshness import HistoryUnavailable, report, require_history, stale_reason
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
    assert f"stale since {second[:7]}" in reason and f"`{COMMAND}`" in reason


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
    assert f"stale since {changes[0][:7]}" in reason  # the oldest: since when
    assert changes[-1][:7] in reason and changes[1][:7] not in reason  # then the newest five


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


def test_the_report_has_one_line_per_table_current_stale_or_missing(repo):
    root, first = repo
    bench_dir = root / "analysis" / "bench"
    for name in ("old", "new"):
        _table(root, first, name)
        (bench_dir / f"{name}.md").write_text("the table\n")
    changed = _commit(root, {"assets/scene.xml": "<changed/>\n"}, "change what old measures")
    measured = {"old": MEASURED, "new": ("platform/hingelab/cli",), "gone": MEASURED}
    lines = report(root, bench_dir, ["old", "new", "gone"], measured.__getitem__)
    assert [stale for _, stale in lines] == [True, False, True]
    old, new, gone = (line for line, _ in lines)
    assert old.startswith("analysis/bench/old.json (recorded at ") and f"stale since {changed[:7]}" in old
    assert old.endswith("run `hingelab bench old`")
    assert new == f"analysis/bench/new.json (recorded at {first[:12]}): current"
    assert gone == "analysis/bench/gone.json: gone.md and gone.json missing; run `hingelab bench gone`"


def test_a_benchmark_with_a_folder_of_its_own_is_looked_for_there(repo):
    root, first = repo
    own = root / "analysis" / "reliability"
    own.mkdir(parents=True)
    _table(root, first, "probes").rename(own / "probes.json")
    (own / "probes.md").write_text("the table\n")
    folders = {"probes": own, "gone": root / "analysis" / "bench"}
    lines = report(root, root / "analysis" / "bench", ["probes", "gone"], lambda name: MEASURED, folders.__getitem__)
    assert lines[0] == (f"analysis/reliability/probes.json (recorded at {first[:12]}): current", False)
    assert lines[1][0].startswith("analysis/bench/gone.json: gone.md and gone.json missing")


def test_the_report_says_when_the_history_cannot_be_read(tmp_path):
    with pytest.raises(HistoryUnavailable, match="not a git checkout"):
        report(tmp_path, tmp_path, ["old"], lambda name: MEASURED)


# --- `hingelab bench --stale` on this repository ------------------------------------------------


def test_bench_stale_reports_every_table_of_this_repository_and_exits_0_stale_or_not(capsys, monkeypatch):
    """One line per benchmark's table, current or stale with the command; not whether they are current.
    (``main`` in this process, from the repository's root as CI runs it: a started process adds only its
    start-up.)"""
    import types

    from hingelab.cli.main import main

    monkeypatch.chdir(REPO_ROOT)
    capsys.readouterr()
    returncode = main(["bench", "--stale"])
    out, err = capsys.readouterr()
    result = types.SimpleNamespace(returncode=returncode, stdout=out, stderr=err)
    try:
        require_history(REPO_ROOT)
    except HistoryUnavailable as exc:  # a shallow or exported copy: the command fails in one line, saying why
        assert result.returncode == 1 and result.stderr.count("\n") == 1, result.stderr
        assert "cannot tell which benchmark tables are stale" in result.stderr
        pytest.skip(f"the tables' history cannot be read here: {exc}")
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert len(lines) == len(BENCHMARKS) + 1, result.stdout  # and a summary
    for name, line in zip(BENCHMARKS, lines):
        assert line.startswith(f"{table_dir(name).relative_to(REPO_ROOT).as_posix()}/{name}.json"), line
        assert line.endswith(": current") or line.endswith(f"run `hingelab bench {name}`"), line
    assert lines[-1].startswith(("all ", f"{sum(not line.endswith(': current') for line in lines[:-1])} of "))


def test_bench_stale_of_one_benchmark_and_its_mistakes(capsys):
    from hingelab.cli.main import main

    if main(["bench", "--stale", "sac"]) == 0:  # (1 without the history: the test above covers that)
        out = capsys.readouterr().out.splitlines()
        assert len(out) == 2 and out[0].startswith("analysis/bench/sac.json")
    for args, said in ((["--stale", "nope"], "unknown benchmark 'nope'"),
                       (["--stale", "--quick"], "--quick does not apply"),
                       ([], "or --stale")):
        capsys.readouterr()
        assert main(["bench", *args]) == 1
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and said in err, err


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
    orphans = [f"analysis/bench/{p.name}" for p in sorted(BENCH_DIR.iterdir())
               if p.is_file() and p.name not in NOT_TABLES and (p.suffix not in (".md", ".json")
                                                                or p.stem not in BENCHMARKS
                                                                or table_dir(p.stem) != BENCH_DIR)]
    assert not orphans, (f"files under analysis/bench/ that no benchmark writes: {orphans}; a kept record "
                         "goes under analysis/bench/history/ with a first line saying what it is")


@pytest.mark.parametrize("name", list(BENCHMARKS))
def test_every_benchmark_has_its_two_tables_recording_the_code_version_they_were_made_with(name):
    """The format, not the freshness: NAME.md and NAME.json (in analysis/bench/, or the benchmark's own
    folder), written together by one run, the json naming the benchmark and the code version (whether that
    version is still current is ``hingelab bench --stale``'s to say)."""
    folder = table_dir(name)
    shown = f"{folder.relative_to(REPO_ROOT).as_posix()}/"
    missing = [f"{name}{ext}" for ext in (".md", ".json") if not (folder / f"{name}{ext}").is_file()]
    assert not missing, f"{shown}: {' and '.join(missing)} missing; run `hingelab bench {name}`"
    table = json.loads((folder / f"{name}.json").read_text())
    assert table["name"] == name
    code = table.get("code")
    assert isinstance(code, dict) and code.get("hingelab_version") and code.get("git_commit"), (
        f"{shown}{name}.json records no code version ({code!r}); run `hingelab bench {name}`")
    assert f"git_commit={code['git_commit']}," in (folder / f"{name}.md").read_text(), (
        f"{shown}{name}.md and .json record different code versions: not written by one run; "
        f"run `hingelab bench {name}`")
