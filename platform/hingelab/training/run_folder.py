"""A training run's folder: what every SAC learner of hingelab writes, and how a run resumes.

::

    RUNDIR/config.json      the resolved config, seed, env id, code version, creation time (and, for
                            train high, ``prior``: the datasets and sources that filled the buffer)
    RUNDIR/run.json         the curve label for ``hingelab report``
    RUNDIR/metrics.csv      one row per evaluation (``MetricsLog``)
    RUNDIR/dataset/         every training rollout, one MCAP episode each (once: a resume removes those
                            that finished after its checkpoint, which it replays)
    RUNDIR/checkpoints/     resumable checkpoints (``hingelab.training.checkpoints``)
    RUNDIR/model.zip        the last policy;  RUNDIR/best_model.zip  the best evaluated one

``RunFolder`` starts a new run (refusing a folder that holds one that started: ``has_started``) or
resumes one (its saved config is kept; only the step budget may grow).
"""

from __future__ import annotations

import csv
import json
import time
from dataclasses import fields, replace
from pathlib import Path

from hingelab.analysis.learning_curves import old_metrics_renames
from hingelab.episodes import create_dataset
from hingelab.episodes.card import EPISODES_DIR
from hingelab.episodes.dataset import Dataset
from hingelab.errors import ConfigError
from hingelab.json_text import strict_dumps
from hingelab.provenance import code_version
from hingelab.seeds import training_episode_seed
from hingelab.training.run_config import flag_of

CONFIG_FILE = "config.json"
RUN_FILE = "run.json"
METRICS_FILE = "metrics.csv"
DATASET_DIR = "dataset"
# what a --resume may change of a run's config.json: how long it runs, what it does with corrupt input, how many
# worker processes share its work (the phase clone's and DAgger's --jobs: the same results with any number)
RESUME_SETTINGS = ("steps", "on_corrupt", "jobs")


class MetricsLog:
    """``metrics.csv``, appended one evaluation at a time (flushed: a crash loses nothing written)."""

    def __init__(self, path: Path):
        self.path = path

    def rows(self) -> list[dict]:
        if not self.path.exists():
            return []
        with open(self.path, newline="") as f:
            return list(csv.DictReader(f))

    def truncate_after(self, env_steps: int) -> None:
        """Drop rows past a checkpoint we resume from (they will be evaluated again). Rows written
        before episode schema 2 (success_rate = last step, settled_success_rate) get today's names,
        so that a resumed run's success_rate is one verdict throughout."""

        rows = [r for r in self.rows() if int(float(r["env_steps"])) <= env_steps]
        renames = old_metrics_renames(rows[0]) if rows else {}
        rows = [{renames.get(k, k): v for k, v in r.items()} for r in rows]
        if self.path.exists():
            self.path.unlink()
        for r in rows:
            self.append(r)

    def _header(self) -> list[str] | None:
        if not self.path.exists():
            return None
        with open(self.path, newline="") as f:
            return next(csv.reader(f), None)

    def append(self, row: dict) -> None:
        """One row, under the file's header (a row's columns in another order go to their own
        columns; a row with new columns rewrites the file under the union, atomically)."""
        header = self._header()
        if header is not None and not set(row) <= set(header):
            rows = self.rows() + [row]
            fields = list(dict.fromkeys([*header, *row]))
            tmp = self.path.with_name(self.path.name + ".tmp")
            with open(tmp, "w", newline="") as f:
                writer = csv.DictWriter(f, fieldnames=fields, restval="")
                writer.writeheader()
                writer.writerows(rows)
                f.flush()
            tmp.replace(self.path)
            return
        with open(self.path, "a", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=header or list(row), restval="")
            if header is None:
                writer.writeheader()
            writer.writerow(row)
            f.flush()


def resumed_config(run_dir: Path, config, given: set[str]):
    """The config a command line's ``--resume`` continues ``run_dir`` with: its ``config.json``, with
    the ``RESUME_SETTINGS`` among the ``given`` flags (``run_config.given_settings``). Any other given
    flag that differs from the run's is refused: the run goes on as it was started, or not at all."""

    path = Path(run_dir) / CONFIG_FILE
    if not path.exists():
        return config  # RunFolder says what is missing
    saved = type(config).load(path)
    by_name = {f.name: f for f in fields(type(config))}
    differing = [f"{flag_of(by_name[name])} ({name}={getattr(config, name)!r}, the run's {getattr(saved, name)!r})"
                 for name in sorted(given - set(RESUME_SETTINGS)) if getattr(config, name) != getattr(saved, name)]
    if differing:
        flags = [flag_of(by_name[n]) for n in RESUME_SETTINGS if n in by_name]
        allowed = " and ".join([", ".join(flags[:-1]), flags[-1]] if len(flags) > 1 else flags)
        raise ConfigError(f"--resume continues {run_dir} as its config.json says, but these flags differ from it: "
                          f"{'; '.join(differing)}. Drop them (a resume may change only {allowed}), "
                          "or start a new run with another --out")
    return replace(saved, **{name: getattr(config, name) for name in RESUME_SETTINGS if name in given})


def covered_episodes(state: dict) -> list[int]:
    """Per rollout env, how many of its episodes a checkpoint covers (its ``state.json``): those the env had
    finished when the checkpoint was written. A checkpoint of an older hingelab records its episode counts
    only: at an episode boundary they are the finished episodes; mid-episode they count the one under way."""
    if "finished_episodes" in state:
        return [int(n) for n in state["finished_episodes"]]
    return [int(n) - (1 if state.get("mid_episode") else 0) for n in state["episode_counts"]]


def has_started(path: Path) -> bool:
    """Whether the run in ``path`` got as far as its first step: an evaluation, a checkpoint, a saved
    policy or a recorded rollout (its config.json, run.json and a generated prior alone do not count)."""
    path = Path(path)
    checkpoints = path / "checkpoints"
    return ((path / METRICS_FILE).exists() or (path / "model.zip").exists()
            or (checkpoints.is_dir() and any(checkpoints.iterdir()))
            or any((path / DATASET_DIR / "episodes").glob("*.mcap")))


class RunFolder:
    """The files of one run; ``config`` is the run's config (the saved one when resuming)."""

    def __init__(self, path: Path, config, resume: bool = False, name: str | None = None):
        self.path = Path(path)
        self.resume = resume
        config_path = self.path / CONFIG_FILE
        if resume:
            if not config_path.exists():
                raise ConfigError(f"cannot resume: {config_path} does not exist; start the run without --resume")
            saved = type(config).load(config_path)
            # RESUME_SETTINGS come from the caller (a run may be extended, not shortened)
            given = {name: getattr(config, name) for name in RESUME_SETTINGS if hasattr(config, name)}
            if "steps" in given:
                given["steps"] = max(config.steps, saved.steps)
            self.config = replace(saved, **given)
        else:
            if config_path.exists() and has_started(self.path):
                raise ConfigError(f"{self.path} already holds a run; continue it with --resume or pass another --out")
            # a start that failed before its first step (a bad --from, a crash while setting up) left only its
            # config: the same command starts it afresh instead of asking for a --resume that would fail alike
            self.config = config
        run_file = self.path / RUN_FILE
        if resume and run_file.exists():  # the dataset card carries the name it was made with
            name = json.loads(run_file.read_text()).get("name", name)
        self.name = name or self.path.name
        self.metrics = MetricsLog(self.path / METRICS_FILE)

    @property
    def dataset_path(self) -> Path:
        return self.path / DATASET_DIR

    def write_run_files(self, extra: dict | None = None) -> None:
        """config.json and run.json of a new run."""
        self.path.mkdir(parents=True, exist_ok=True)
        doc = {"config": self.config.to_dict(), "seed": self.config.seed, "env_id": self.config.env_id,
               **(extra or {}), **code_version(), "created": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
        (self.path / CONFIG_FILE).write_text(strict_dumps(doc, self.path / CONFIG_FILE, indent=2))
        (self.path / RUN_FILE).write_text(strict_dumps({"name": self.name}, self.path / RUN_FILE))

    def record_run_fact(self, key: str, value) -> None:
        """Add ``key`` to config.json (JSON), e.g. the datasets that filled the replay buffer, known only
        once they are read; the config itself is not touched (``--resume`` reads only it)."""
        path = self.path / CONFIG_FILE
        doc = json.loads(path.read_text())
        doc[key] = value
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(strict_dumps(doc, tmp, indent=2))
        tmp.replace(path)

    def dataset(self, description: str) -> Path | None:
        """The rollouts' dataset folder (created with its card for a new run; a resumed run keeps its
        card and drops the episodes that were running when it stopped: they are replayed from their
        seeds). None when the config does not record."""
        if not self.config.record:
            return None

        root = self.dataset_path
        dataset_config = {k: v for k, v in self.config.to_dict().items() if k != "steps"}
        if not (self.resume and (root / "dataset.json").exists()):
            create_dataset(root, name=f"{self.name}-rollouts", source=self.config.train_source, config=dataset_config,
                           seed=self.config.seed, description=description)
        if self.resume:
            for partial in (root / "episodes").glob("*.partial"):
                partial.unlink()
        return root

    def drop_rollouts_after(self, covered: list[int]) -> list[str]:
        """Remove the recorded rollouts that finished after the checkpoint a resume continues from
        (``covered``: per env, the episodes it covers, ``covered_episodes``); returns their file names.

        The resumed run replays those episodes from their seeds (``training_episode_seed``), so the
        dataset ends as an uninterrupted run's, each rollout once. They are removed, not set aside in a
        folder of their own: the replay is the same episode (the run resumes exactly), and a second copy
        anywhere in the run folder is one a later glob could count again. A covered seed recorded twice
        (a run resumed by an older hingelab) keeps its last episode, the replay the checkpoint learned from."""
        episodes = self.dataset_path / EPISODES_DIR
        if not self.config.record or not episodes.is_dir():
            return []
        seed = self.config.seed
        kept = {training_episode_seed(seed, env, k) for env, n in enumerate(covered) for k in range(n)}
        index = Dataset(self.dataset_path, on_corrupt=getattr(self.config, "on_corrupt", None)).build_index()
        rollouts = index.dropna(subset=["seed"]).sort_values("file")  # episode ids sort by the time they began
        covered_rows = rollouts["seed"].astype(int).isin(kept)
        drop = list(rollouts["file"][~covered_rows | rollouts["seed"].duplicated(keep="last")])
        for name in drop:
            (episodes / name).unlink()
        return drop


__all__ = ["RunFolder", "has_started", "covered_episodes", "MetricsLog", "CONFIG_FILE", "METRICS_FILE", "DATASET_DIR",
           "RUN_FILE"]
