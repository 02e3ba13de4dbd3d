"""Provenance: "dirty" is about the code and the models, and committed results refuse dirty code."""

from __future__ import annotations

import subprocess

import pytest

from hingelab import provenance
from hingelab.errors import ConfigError


def _git(root, *args):
    subprocess.run(["git", "-C", str(root), *args], check=True, capture_output=True)


@pytest.fixture
def checkout(tmp_path, monkeypatch):
    """A small repository with the project's top-level folders, one commit."""
    root = tmp_path / "repo"
    for rel, text in {"platform/hingelab/a.py": "x = 1\n", "assets/m.xml": "<m/>\n",
                      "pyproject.toml": "[project]\n", "analysis/r.md": "old\n", "README.md": "hi\n",
                      ".gitignore": "/analysis/demo/\n"}.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(text)
    _git(root, "init", "-q")
    _git(root, "add", ".")
    _git(root, "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-q", "-m", "init")
    monkeypatch.setattr(provenance, "REPO_ROOT", root)
    monkeypatch.setattr(provenance, "ANALYSIS_DIR", root / "analysis")
    provenance.git_commit.cache_clear()
    yield root
    provenance.git_commit.cache_clear()


def _version():
    provenance.git_commit.cache_clear()
    return provenance.git_commit()


def test_results_and_docs_do_not_make_the_code_dirty(checkout):
    head = subprocess.run(["git", "-C", str(checkout), "rev-parse", "HEAD"], capture_output=True,
                          text=True, check=True).stdout.strip()
    (checkout / "analysis" / "r.md").write_text("new\n")
    (checkout / "analysis" / "new.csv").write_text("a\n")
    (checkout / "README.md").write_text("changed\n")
    assert _version() == head
    provenance.require_clean_for(checkout / "analysis" / "bench", False, "test")


@pytest.mark.parametrize("rel", ["platform/hingelab/a.py", "assets/m.xml", "pyproject.toml",
                                 "platform/hingelab/new_module.py"])
def test_code_model_and_dependency_changes_are_dirty_with_a_hash_of_the_change(checkout, rel):
    head = _version()
    (checkout / rel).write_text("changed\n")
    dirty = _version()
    assert dirty.startswith(head + "+dirty.") and len(dirty.split(".")[-1]) == 12
    assert _version() == dirty  # the same change, the same hash
    (checkout / rel).write_text("changed again\n")
    assert _version() not in (dirty, head)
    with pytest.raises(ConfigError, match=rf"{rel}.*--allow-dirty"):
        provenance.require_clean_for(checkout / "analysis" / "bench", False, "hingelab bench sim")
    provenance.require_clean_for(checkout / "analysis" / "bench", True, "hingelab bench sim")
    provenance.require_clean_for(checkout / "elsewhere", False, "hingelab bench sim")
    provenance.require_clean_for(checkout / "analysis" / "demo", False, "hingelab demo")  # git-ignored
