"""``load_policy``: any policy of the platform from what names it, found through a registry.

A checkpoint is recognised by its format (``register_policy_format``: a name, a test of the file and
its loader), a baseline by its name (``register_baseline``). The built-in formats (a stable-baselines3
SAC zip of ToolShape-v0 or ToolPick-v0, the low-level experts manifest, the phase clone) and baselines
(``heuristic``, ``scripted``, ``scripted-observed``, ``scripted-feedback``, ``random``, ``hold-still``,
``synergy``) register when ``hingelab.policies`` is imported; a learner of its own format registers it
in its own folder (``hingelab.learners``), so loading its checkpoints needs no edit here.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from hingelab.errors import ConfigError


@dataclass(frozen=True)
class PolicyFormat:
    name: str
    matches: Callable[[Path], bool]  # is this file of the format (cheap: reads a header or a zip's entry list)
    load: Callable[..., object]  # load(path, *, encoder, low_level, level) -> Policy (context it may ignore)


@dataclass(frozen=True)
class Baseline:
    name: str
    level: str  # "low" (ToolShape-v0) or "high" (ToolPick-v0)
    make: Callable[..., object]  # make(env=None) -> a Policy or an EpisodePolicy
    description: str


FORMATS: dict[str, PolicyFormat] = {}
BASELINES: dict[str, Baseline] = {}


def register_policy_format(name: str, matches: Callable[[Path], bool], load: Callable[..., object]) -> None:
    """Add a checkpoint format; formats are tried in the order they registered, so a specific test
    registers before a general one. Registering a name again replaces it."""
    FORMATS[name] = PolicyFormat(name, matches, load)


def register_baseline(name: str, level: str, make: Callable[..., object], description: str = "") -> None:
    if level not in ("low", "high"):
        raise ValueError(f"a baseline acts on the low or the high level, not {level!r}")
    BASELINES[name] = Baseline(name, level, make, description)


def baseline_names(level: str) -> tuple[str, ...]:
    return tuple(name for name, b in BASELINES.items() if b.level == level)


def policy_format(path) -> PolicyFormat:
    """The registered format of the checkpoint at ``path`` (a file, or a run folder's model.zip)."""
    path = checkpoint_file(path)
    for fmt in FORMATS.values():
        if fmt.matches(path):
            return fmt
    raise ConfigError(f"{path} is not a policy checkpoint of a known format ({', '.join(FORMATS)}); give a "
                      "checkpoint from `hingelab train ...` or `hingelab compose low`")


def checkpoint_file(path) -> Path:
    """A file, or the ``model.zip`` of a folder (a run folder, a ``checkpoints/step_*`` folder)."""
    path = Path(path)
    if path.is_dir():
        if not (path / "model.zip").is_file():
            raise ConfigError(f"{path} is a folder without a model.zip; give a run folder or a checkpoint file")
        path = path / "model.zip"
    if not path.is_file():
        raise ConfigError(f"no policy checkpoint at {path}; give a checkpoint file or a run folder")
    return path


def load_policy(spec, *, level: str | None = None, encoder=None, low_level: str | None = None, env=None):
    """The policy ``spec`` names: a baseline's name (``env``: the env it acts in, for the baselines that
    read it) or a checkpoint path, loaded by its format. ``level``: ``"low"`` (ToolShape-v0) or ``"high"``
    (ToolPick-v0), the task the policy must fit (None: whichever the file is of); ``encoder``: the tool
    encoder the env perceives with (a low-level checkpoint is checked against it); ``low_level``: the low
    level a high-level policy will act over (checked against the one it learned beside)."""
    if isinstance(spec, str) and spec in BASELINES:
        baseline = BASELINES[spec]
        if level is not None and baseline.level != level:
            raise ConfigError(f"{spec} is a {baseline.level}-level baseline; the {level} level's: "
                              f"{', '.join(baseline_names(level))}")
        return baseline.make(env=env)
    path = checkpoint_file(spec)
    return policy_format(path).load(path, encoder=encoder, low_level=low_level, level=level)


__all__ = ["PolicyFormat", "Baseline", "FORMATS", "BASELINES", "register_policy_format", "register_baseline",
           "baseline_names", "policy_format", "checkpoint_file", "load_policy"]
