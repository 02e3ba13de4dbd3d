"""The lock (constraints.txt) pins every dependency the test and bench extras install, within pyproject's bounds."""

from __future__ import annotations

import tomllib
from pathlib import Path

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

ROOT = Path(__file__).resolve().parents[1]


def _pins() -> dict[str, Version]:
    pins = {}
    for line in (ROOT / "constraints.txt").read_text().splitlines():
        line = line.split("#")[0].strip()
        if line:
            name, _, version = line.partition("==")
            assert version, f"constraints.txt: {line!r} is not NAME==VERSION"
            pins[canonicalize_name(name)] = Version(version)
    return pins


def test_every_declared_dependency_is_pinned_within_its_bounds():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    declared = project["dependencies"] + [r for extra in ("test", "bench")
                                          for r in project["optional-dependencies"][extra]]
    pins = _pins()
    for text in declared:
        requirement = Requirement(text)
        name = canonicalize_name(requirement.name)
        assert name in pins, f"{requirement.name} is declared in pyproject.toml but not pinned in constraints.txt"
        assert requirement.specifier.contains(pins[name], prereleases=True), \
            f"constraints.txt pins {name}=={pins[name]} outside pyproject.toml's {requirement}"


def test_the_known_incompatible_releases_are_kept_out():
    pins = _pins()
    assert pins["stable-baselines3"] >= Version("2.7")  # ReplayBufferSamples.discounts (learners/sac/fast_sac.py)
    assert pins["numpy"].major == 2
    assert pins["torch"] == Version("2.13.0")  # the CPU build on local disk
