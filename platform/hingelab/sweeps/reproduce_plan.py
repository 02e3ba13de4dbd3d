"""The stages of ``hingelab reproduce``: the shipped set's recipes as ``hingelab`` command lines.

Every recipe below is the command that made a shipped asset (``assets/checkpoints/README.md``,
``analysis/low-level-experts/README.md``, ``analysis/high-level/README.md``), with the same flags and seeds;
``plan_stages`` adds each stage's ``--out`` (``DIR/stages/NAME``) and the paths of the products it builds
on. ``--scale tiny`` replaces the sizes (steps, episodes, clouds, epochs) by ``TINY``'s, so the whole
pipeline runs in minutes for tests and smoke runs; the commands are otherwise the same.

The reproduced encoder reaches the later stages through ``HINGELAB_ASSETS`` (``hingelab.paths``): the
stages that perceive the tool run with ``HINGELAB_ASSETS=DIR/assets``, a copy of the assets folder made of
links, whose ``checkpoints/encoder.pt`` is the encoder stage's checkpoint. An env argument
(``--env-kwargs '{"encoder_path": ...}'``) would not do: ``train low`` records the shipped encoder's
fingerprint whatever encoder its envs use, ``train high`` likewise, and ``eval low``, ``eval high`` and
``compose low`` check policies against the shipped encoder and take no encoder argument. Under the linked
assets the "shipped" encoder of those commands is the reproduced one, as it was in the checkout where the
shipped policies were trained (``assets/checkpoints/README.md``). The reproduced low level is passed by path
(``--low-level``), the high level fits its own base clone (``--base fit``) and its evaluations take the reproduced
checkpoints by path; ``DIR/assets/checkpoints`` holds no policy, so no stage can fall back on a shipped one
unnoticed.
"""

from __future__ import annotations

import shlex
from dataclasses import asdict, dataclass
from pathlib import Path

from hingelab.errors import ConfigError
from hingelab.paths import ASSETS_DIR

STAGES_DIR, LOGS_DIR, ASSETS_LINK_DIR = "stages", "logs", "assets"

# ---------------------------------------------------------------------------- the recipes (the shipped flags)
# assets/checkpoints/README.md, encoder v3
CLOUDS = ("generate", "clouds", "--n", "20000", "--noise", "0.002", "--noise-max", "0.006", "--seed", "0")
ENCODER = ("train", "encoder", "--epochs", "24", "--seed", "0", "--threads", "1")
# assets/checkpoints/README.md, policy v3 (low_level.zip) and the closed expert (low_level_closed.zip)
LOW_DEMOS = ("eval", "low", "--baseline", "synergy", "--episodes", "200", "--seed", "11")
LOW_SAC = ("train", "low", "--envs", "1", "--in-process", "--buffer-size", "200000", "--learning-starts", "1000",
           "--eval-every", "2500", "--eval-goals", "5", "--bc-weight", "1", "--bc-no-q-filter", "--bc-pretrain", "2000",
           "--drift-weight", "60")
LOW_OPEN = ("--steps", "50000", "--seed", "2")
LOW_CLOSED = ("--steps", "40000", "--seed", "4", "--goal-openings=-1:0.10")
CLOSED_UP_TO_RAD = "0.10"  # compose low: the closed expert serves goals up to this opening
# Both cores for the high level's run: its prior, fits and rollouts in 2 workers, the same products as one process
# (tests/test_dagger_jobs.py), about twice as fast on an idle machine; the stages beside it are short evaluations.
HIGH_JOBS = ("--jobs", "2")
# assets/checkpoints/README.md, the shipped high level (high_level.zip): one DAgger run that fits its own phase
# clone on the prior first (RUNDIR/base.zip), then 4 rounds over it (RUNDIR/model.zip, the last round's clone)
HIGH_DAGGER = ("train", "high", "--learner", "dagger", "--base", "fit",
               "--env-kwargs", '{"observe_extent": true, "tool_position": "relative"}', "--prior-objects", "all",
               "--prior-episodes", "720", "--net-arch", "512", "512", "--clone-members", "3",
               "--rollout-objects", "all", "--dagger-rounds", "4", "--dagger-episodes", "120", "--eval-episodes", "30",
               "--seed", "0", *HIGH_JOBS)

# What the final table measures (hingelab.sweeps.reproduce_table): fresh seeds no choice was made on for the
# reproduction; the goal seed 3 and the pick seeds 1200 are the seeds of the shipped assets' reported figures.
COMPARISON = {"encoder_clouds": 1000, "encoder_noise_m": 0.005, "encoder_seed": 2027,
              "low_goals": 100, "low_seed": 3,
              "pick_sets": (("sphere", 0.025), ("tetrahedron", 0.015), ("cube", 0.02)), "pick_episodes": 20,
              "pick_seed": 1200}

# --scale tiny: flag values that replace the recipe's (a tuple: a flag of several values); sizes only
_TINY_LOW = {"--buffer-size": "2000", "--learning-starts": "50", "--eval-every": "150", "--eval-goals": "1",
             "--bc-pretrain": "10", "--checkpoint-every": "50", "--steps": "150"}
TINY = {
    "clouds": {"--n": "300", "--per-episode": "30"},
    "encoder": {"--epochs": "1"},
    "low_demos": {"--episodes": "3"},
    "low_open": _TINY_LOW,
    "low_closed": _TINY_LOW,
    "high": {"--prior-episodes": "12", "--net-arch": ("16", "16"), "--clone-members": "2", "--clone-updates": "20",
             "--dagger-rounds": "1", "--dagger-episodes": "2", "--dagger-updates": "20", "--eval-episodes": "1",
             "--jobs": "1"},  # tiny: spawning workers would cost more than the work
}
TINY_COMPARISON = {"encoder_clouds": 100, "low_goals": 2, "pick_sets": (("sphere", 0.02),), "pick_episodes": 1}
SCALES = ("shipped", "tiny")

# How a stage that stopped part-way goes on: its command's own --resume, when the folder holds what that
# resume needs, or a fresh start in an emptied folder.
RESUME_KINDS = {
    "none": "no --resume: started again from scratch",
    "eval": "eval --resume (its journal of finished episodes)",
    "sac": "train --resume from the last checkpoint (none yet: started again)",
    "dagger": "train --resume after the last saved round, keeping the written prior and the fitted base.zip (a cut-off "
              "round's rollouts are made again)",
}


@dataclass(frozen=True)
class Stage:
    """One ``hingelab`` command of the reproduction. ``argv``: its arguments (absolute paths);
    ``outputs``: the files it must leave, relative to the reproduction folder; ``reproduced_assets``: run
    with ``HINGELAB_ASSETS`` at the linked assets (the reproduced encoder)."""

    name: str
    argv: tuple[str, ...]
    deps: tuple[str, ...]
    resume: str
    outputs: tuple[str, ...]
    reproduced_assets: bool
    product: str = ""  # the shipped asset it builds or measures, for the table

    def to_dict(self) -> dict:
        return {**asdict(self), "argv": list(self.argv), "deps": list(self.deps), "outputs": list(self.outputs)}


def with_flags(argv: tuple[str, ...], overrides: dict) -> tuple[str, ...]:
    """``argv`` with each flag's value(s) replaced by ``overrides[flag]`` (a string or a tuple of them), or the
    flag appended when ``argv`` lacks it; ``--flag=value`` tokens count as the flag."""
    out, i, seen = [], 0, set()
    while i < len(argv):
        token = argv[i]
        flag = token.split("=", 1)[0] if token.startswith("--") else None
        if flag in overrides:
            seen.add(flag)
            i += 1
            if "=" not in token:  # skip the old value(s)
                while i < len(argv) and not argv[i].startswith("--"):
                    i += 1
            value = overrides[flag]
            out += [flag, *(value if isinstance(value, tuple) else (value,))]
            continue
        out.append(token)
        i += 1
    for flag, value in overrides.items():
        if flag not in seen:
            out += [flag, *(value if isinstance(value, tuple) else (value,))]
    return tuple(out)


def comparison(scale: str) -> dict:
    return {**COMPARISON, **(TINY_COMPARISON if scale == "tiny" else {})}


def pick_stage_name(policy: str, shape: str, size: float) -> str:
    return f"picks_{policy}_{shape}_{round(size * 1000)}mm"


def plan_stages(out: Path, scale: str = "shipped") -> list[Stage]:
    """The stages in dependency order (each after the stages it names in ``deps``)."""
    if scale not in SCALES:
        raise ConfigError(f"--scale {scale}: choose one of {', '.join(SCALES)}")
    out = Path(out).resolve()
    stages_dir = out / STAGES_DIR
    tiny = TINY if scale == "tiny" else {}

    def folder(name: str) -> str:
        return str(stages_dir / name)

    def stage(name, argv, deps, resume, outputs, reproduced_assets=True, product=""):
        argv = with_flags(tuple(argv), tiny.get(name, {}))
        return Stage(name, argv, tuple(deps), resume, tuple(f"{STAGES_DIR}/{name}/{o}" for o in outputs),
                     reproduced_assets, product)

    experts = f"{folder('low_experts')}/low_level_experts.json"
    base, dagger = f"{folder('high')}/base.zip", f"{folder('high')}/model.zip"
    plan = [
        stage("clouds", [*CLOUDS, "--out", folder("clouds")], [], "none", ["dataset.json"], False, "encoder.pt"),
        stage("encoder", [*ENCODER, "--data", folder("clouds"), "--out", f"{folder('encoder')}/encoder.pt"],
              ["clouds"], "none", ["encoder.pt"], False, "encoder.pt"),
        stage("low_demos", [*LOW_DEMOS, "--out", folder("low_demos")], ["encoder"], "eval", ["episodes.csv"],
              product="low_level_experts.json"),
        stage("low_open", [*LOW_SAC, *LOW_OPEN, "--from", folder("low_demos"), "--out", folder("low_open")],
              ["low_demos"], "sac", ["model.zip"], product="low_level.zip"),
        stage("low_closed", [*LOW_SAC, *LOW_CLOSED, "--from", folder("low_demos"), "--out", folder("low_closed")],
              ["low_demos"], "sac", ["model.zip"], product="low_level_closed.zip"),
        stage("low_experts", ["compose", "low", "--expert", f"{folder('low_closed')}/model.zip:{CLOSED_UP_TO_RAD}",
                              "--expert", f"{folder('low_open')}/model.zip", "--out", experts],
              ["low_open", "low_closed"], "none", ["low_level_experts.json"], product="low_level_experts.json"),
        stage("high", [*HIGH_DAGGER, "--low-level", experts, "--out", folder("high")], ["low_experts"], "dagger",
              ["model.zip", "base.zip"], product="high_level.zip"),
    ]
    c = comparison(scale)
    low_eval = ("eval", "low", "--episodes", str(c["low_goals"]), "--seed", str(c["low_seed"]))
    plan += [stage("eval_low_reproduced", [*low_eval[:2], experts, *low_eval[2:], "--out",
                                           folder("eval_low_reproduced")],
                   ["low_experts"], "eval", ["episodes.csv"], product="low_level_experts.json"),
             stage("eval_low_shipped", [*low_eval, "--out", folder("eval_low_shipped")], [], "eval",
                   ["episodes.csv"], False, "low_level_experts.json")]
    policies = (("clone", base, ["high"], True), ("dagger", dagger, ["high"], True), ("shipped", None, [], False))
    for policy, checkpoint, deps, reproduced in policies:
        for shape, size in c["pick_sets"]:
            name = pick_stage_name(policy, shape, size)
            argv = ["eval", "high", *([checkpoint] if checkpoint else []), "--object", shape, "--size", f"{size:g}",
                    "--episodes", str(c["pick_episodes"]), "--seed", str(c["pick_seed"]), "--out", folder(name)]
            plan.append(stage(name, argv, deps, "eval", ["episodes.csv"], reproduced, "high_level.zip"))
    return plan


# ---------------------------------------------------------------------------- the linked assets
def stage_environment(stage: Stage, out: Path) -> dict:
    """The environment variables a stage runs with, besides the caller's."""
    return {"HINGELAB_ASSETS": str(Path(out).resolve() / ASSETS_LINK_DIR)} if stage.reproduced_assets else {}


def link_assets(out: Path, source: Path = ASSETS_DIR) -> Path:
    """``DIR/assets``: a link to every entry of the assets folder but ``checkpoints``, and a ``checkpoints``
    folder whose ``encoder.pt`` links to the encoder stage's checkpoint (dangling until that stage is done).
    Made again where missing; returns the folder."""
    root = Path(out) / ASSETS_LINK_DIR
    (root / "checkpoints").mkdir(parents=True, exist_ok=True)
    for entry in sorted(Path(source).iterdir()):
        link = root / entry.name
        if entry.name != "checkpoints" and not link.is_symlink() and not link.exists():
            link.symlink_to(entry.resolve(), target_is_directory=entry.is_dir())
    encoder = root / "checkpoints" / "encoder.pt"
    if not encoder.is_symlink():
        encoder.symlink_to(Path("..") / ".." / STAGES_DIR / "encoder" / "encoder.pt")
    readme = root / "checkpoints" / "README.md"
    if not readme.exists():
        readme.write_text("# Reproduced assets (hingelab reproduce)\n\nThe stages that perceive the tool ran with "
                          "HINGELAB_ASSETS set to this folder: every entry links to the assets of the checkout, but "
                          "`checkpoints/encoder.pt`, which links to the encoder stage's checkpoint. The reproduced "
                          "policies are in `../../stages/`; `../../reproduce.md` compares them with the shipped "
                          "ones.\n")
    return root


def describe_plan(stages: list[Stage], out: Path) -> str:
    """The plan as text: one line per stage (name, what it waits for, how it resumes) and its command."""
    lines = []
    for s in stages:
        env = " ".join(f"{k}={v}" for k, v in stage_environment(s, out).items())
        after = f" after {', '.join(s.deps)}" if s.deps else ""
        lines.append(f"{s.name}{after} [{RESUME_KINDS[s.resume]}]\n    {env + ' ' if env else ''}hingelab "
                     + shlex.join(s.argv))
    return "\n".join(lines)


__all__ = ["CLOUDS", "ENCODER", "LOW_DEMOS", "LOW_SAC", "LOW_OPEN", "LOW_CLOSED", "HIGH_DAGGER", "HIGH_JOBS",
           "COMPARISON", "TINY", "TINY_COMPARISON", "SCALES", "RESUME_KINDS", "Stage", "comparison", "describe_plan",
           "link_assets", "pick_stage_name", "plan_stages", "stage_environment", "with_flags", "STAGES_DIR", "LOGS_DIR",
           "ASSETS_LINK_DIR"]
