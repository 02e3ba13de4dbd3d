"""A low-level policy made of experts, one per band of goal openings: the goal picks the expert.

Policies of one recipe differ most by goal region, seed to seed (the per-region rates:
``analysis/low-level-encoder-v3``), so an expert trained on one band can be chosen per band. The goal
is part of the observation, so routing on it is a policy pi(a | s, g) like any other: each
expert is an unchanged ``hingelab train low`` checkpoint, checked against the env's encoder as
any checkpoint is, and the band is read from the goal latent by the encoder's calibration
(the nearest point of the curve: exact for goals on it). Made by ``hingelab compose low``.

The manifest is JSON beside the checkpoints (paths relative to its folder)::

    {"format": "hingelab-low-level-experts", "format_version": 1,
     "experts": [{"checkpoint": "low_level_closed.zip", "up_to_rad": 0.10, "sha256": "..."},
                 {"checkpoint": "low_level.zip", "up_to_rad": null, "sha256": "..."}],
     "created": "...", "hingelab_version": "...", "git_commit": "..."}

An expert serves goals whose opening is at most its ``up_to_rad`` and above the previous
one's; the last has none (all the goals above). A checkpoint that changed since the manifest
was written (its sha256) is refused.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from pathlib import Path

import numpy as np

from hingelab.errors import ConfigError
from hingelab.json_text import strict_dumps
from hingelab.perception.encoder import shipped_encoder
from hingelab.policies.loading import register_policy_format
from hingelab.policies.low_level import load_sac_checkpoint
from hingelab.provenance import code_version

FORMAT = "hingelab-low-level-experts"
FORMAT_VERSION = 1


class GoalRegionExperts:
    """``predict(obs, deterministic=True)`` as a stable-baselines3 model's, each goal by its expert.

    ``experts``: SAC models, in the order of ``bounds_rad`` (the upper openings of all but the
    last); ``calibration``: the encoder's, reading a goal latent's opening.
    """

    def __init__(self, experts: list, bounds_rad: list[float], calibration, provenance: dict):
        if len(experts) != len(bounds_rad) + 1:
            raise ConfigError(f"{len(experts)} experts need {len(experts) - 1} band bounds, got {len(bounds_rad)}")
        if list(bounds_rad) != sorted(bounds_rad) or len(set(bounds_rad)) != len(bounds_rad):
            raise ConfigError(f"the experts' up_to_rad must increase, got {bounds_rad}")
        self.experts = experts
        self.bounds_rad = np.asarray(bounds_rad, float)
        self.calibration = calibration
        self.hingelab_provenance = provenance
        self.observation_space = experts[0].observation_space
        self.action_space = experts[0].action_space

    def expert_index(self, desired_goal: np.ndarray) -> np.ndarray:
        """(B,) which expert serves each goal latent (B, 2): the band of its opening."""
        openings = self.calibration.project_opening(np.atleast_2d(np.asarray(desired_goal, float)))
        return np.searchsorted(self.bounds_rad, openings, side="left")

    def predict(self, observation: dict, state=None, episode_start=None, deterministic: bool = True):
        goals = np.asarray(observation["desired_goal"], float)
        if goals.ndim == 1:  # one unbatched observation: one expert
            return self.experts[int(self.expert_index(goals)[0])].predict(observation, deterministic=deterministic)
        which = self.expert_index(goals)
        actions = np.empty((len(goals), *self.action_space.shape), dtype=self.action_space.dtype)
        for k in np.unique(which):
            rows = which == k
            part = {key: np.asarray(value)[rows] for key, value in observation.items()}
            actions[rows], _ = self.experts[int(k)].predict(part, deterministic=deterministic)
        return actions, None


def file_sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _merged_provenance(manifest: Path, models: list, bounds: list[float]) -> dict:
    """The last expert's provenance (its config sets the eval env: episode length, reward weights),
    with the experts and their bands listed."""
    own = [getattr(m, "hingelab_provenance", None) or {} for m in models]
    return {**own[-1], "policy": "goal-region experts", "manifest": str(manifest),
            "experts": [{"up_to_rad": b, "git_commit": p.get("git_commit", "unknown"), "seed": p.get("seed")}
                        for b, p in zip([*bounds, None], own)]}


def load_experts(manifest: str | Path, encoder=None) -> GoalRegionExperts:
    """Read a manifest and load its experts (each checked as ``PolicyLowLevel`` checks a checkpoint)."""
    manifest = Path(manifest)
    try:
        raw = json.loads(manifest.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ConfigError(f"cannot read the experts manifest {manifest}: {exc}") from exc
    if not isinstance(raw, dict) or raw.get("format") != FORMAT:
        raise ConfigError(f"{manifest} is not a {FORMAT} manifest; make one with `hingelab compose low`")
    if raw.get("format_version") != FORMAT_VERSION:
        raise ConfigError(f"{manifest} has format_version {raw.get('format_version')}; this hingelab reads "
                          f"{FORMAT_VERSION}")
    entries = raw.get("experts") or []
    if len(entries) < 2 or entries[-1].get("up_to_rad") is not None or \
            any(e.get("up_to_rad") is None for e in entries[:-1]):
        raise ConfigError(f"{manifest}: give at least two experts, each but the last with an up_to_rad")
    encoder = encoder if encoder is not None else shipped_encoder()
    if encoder.calibration is None:
        raise ConfigError("goal-region experts need an encoder with a calibration (to read a goal's opening)")
    models = []
    for entry in entries:
        path = (manifest.parent / entry["checkpoint"]).resolve()
        if not path.is_file():
            raise ConfigError(f"{manifest}: expert checkpoint {path} does not exist")
        if entry.get("sha256") and file_sha256(path) != entry["sha256"]:
            raise ConfigError(f"{manifest}: {path} changed since the manifest was made; compose it again with "
                              "`hingelab compose low`")
        models.append(load_sac_checkpoint(path, encoder))
    bounds = [float(e["up_to_rad"]) for e in entries[:-1]]
    return GoalRegionExperts(models, bounds, encoder.calibration, _merged_provenance(manifest, models, bounds))


def write_experts(out: str | Path, experts: list[tuple[Path, float | None]], encoder=None) -> Path:
    """Check the experts load together (each against the encoder), then write the manifest ``out``
    (atomically); paths are stored relative to its folder. Returns ``out``."""
    out = Path(out)
    if out.suffix != ".json":
        raise ConfigError(f"the experts manifest is a .json file, not {out}")
    resolved = []
    for checkpoint, up_to in experts:
        path = Path(checkpoint)
        if path.is_dir():
            path = path / "model.zip"
        if not path.is_file():
            raise ConfigError(f"expert checkpoint {path} does not exist")
        resolved.append((path.resolve(), up_to))
    out.parent.mkdir(parents=True, exist_ok=True)
    base = out.parent.resolve()
    entries = [{"checkpoint": os.path.relpath(path, base), "up_to_rad": None if up_to is None else float(up_to),
                "sha256": file_sha256(path)} for path, up_to in resolved]
    manifest = {"format": FORMAT, "format_version": FORMAT_VERSION, "experts": entries,
                "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"), **code_version()}
    tmp = out.with_name(out.name + ".tmp")
    tmp.write_text(strict_dumps(manifest, tmp, indent=2) + "\n")
    try:
        load_experts(tmp, encoder)  # refuse a manifest that would not load (bands, fingerprints, spaces)
    except Exception:
        tmp.unlink()
        raise
    tmp.replace(out)
    return out



def is_experts_manifest(path) -> bool:
    """A JSON file whose ``format`` is the experts manifest's."""
    path = Path(path)
    if path.suffix != ".json":
        return False
    try:
        return json.loads(path.read_text()).get("format") == FORMAT
    except (OSError, ValueError, AttributeError):
        return False


def _load(path, encoder=None, low_level=None, level=None):
    if level == "high":
        raise ConfigError(f"{path} is a low-level experts manifest; give a high-level checkpoint")
    return load_experts(path, encoder)


register_policy_format(FORMAT, is_experts_manifest, _load)

__all__ = ["FORMAT", "GoalRegionExperts", "load_experts", "write_experts"]
