"""The pick table in one command (``hingelab eval picks``): one policy on each of the pick table's sets.

Each set (a shape and a size of ``hingelab.sim.objects.PICK_SETS``, or the ``--sets`` given: shapes and sizes, or
object families with their size caps) is an ordinary
``eval high`` dataset in ``OUT/SHAPE_NNmm`` with the same episode seeds as any other policy's evaluation at
that seed, so two policies' tables pair episode by episode (``hingelab report --picks A B`` counts the
episodes one picked and the other missed). ``OUT/picks.json`` records what is evaluated (the policy, seed,
episodes, sets and the ``eval high`` settings); ``--resume`` checks it and continues: finished sets are kept,
a cut-off set goes on from its last whole episode. At the end ``OUT/picks.md`` and ``picks.csv``
(``hingelab.analysis.pick_table``) pool the sets.

Sets run one after another, or ``jobs`` at a time in spawned processes (one torch thread each).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from hingelab.errors import ConfigError
from hingelab.provenance import differing_settings

PICKS_FILE = "picks.json"


def parse_sets(texts) -> tuple[tuple[str, float], ...]:
    """``OBJECT:SIZE_M`` texts as (object, size) pairs: a shape (``sphere:0.025``, size in metres) or a family
    (``family:prism3:0.03`` or ``family:prism3:7:0.03``, the size its cap); None or empty: the pick table's 12
    sets."""
    from hingelab.sim.object_families import ObjectFamily, is_family
    from hingelab.sim.objects import PICK_SETS, SHAPES

    if not texts:
        return tuple(PICK_SETS)
    sets = []
    for text in texts:
        name, _, size = str(text).rpartition(":")
        try:
            value = float(size)
        except ValueError:
            value = float("nan")
        if is_family(name):
            ObjectFamily.parse(name, value)  # a one-line error naming the families or the size range
        elif name not in SHAPES or not 0.005 <= value <= 0.05:
            raise ConfigError(f"--sets {text}: give SHAPE:SIZE with SHAPE one of {', '.join(SHAPES)} and SIZE in "
                              "metres, 0.005 to 0.05 (e.g. sphere:0.025), or family:NAME[:SEED]:SIZE_CAP "
                              "(e.g. family:prism3:0.03)")
        sets.append((name, value))
    if len(set(sets)) != len(sets):
        raise ConfigError(f"--sets names a set twice: {' '.join(map(str, texts))}")
    return tuple(sets)


def set_folder(out: Path, shape: str, size: float) -> Path:
    """``OUT/sphere_25mm``, ``OUT/family_prism3_30mm``."""
    return Path(out) / f"{shape.replace(':', '_')}_{round(size * 1000)}mm"


def _finished(folder: Path) -> bool:
    """An ``eval high`` that ran to its end: its episodes.csv written and its journal of a stopped run gone."""
    from hingelab.rollouts.journal import JOURNAL_FILE

    return (folder / "episodes.csv").is_file() and not (folder / JOURNAL_FILE).exists()


def _evaluate_one(job: dict) -> str:
    """One set's ``eval high`` (a worker's item, or called in this process)."""
    from hingelab.rollouts.evaluation import evaluate_high

    if job.pop("single_thread", False):
        import torch

        torch.set_num_threads(1)
    folder = Path(job["out"])
    resume = folder.exists() and any(folder.iterdir())
    result = evaluate_high(**job, resume=resume)
    return result.summary


def _record(out: Path, settings: dict, resume: bool) -> None:
    path = out / PICKS_FILE
    if path.is_file():
        recorded = json.loads(path.read_text())
        if not resume:
            raise ConfigError(f"{out} already holds a pick-table evaluation ({path}); add --resume to continue it "
                              "or give a new --out")
        changed = differing_settings(recorded, settings)
        if changed:
            raise ConfigError(f"--resume {out}: its evaluation was made with other settings ({', '.join(changed)} "
                              f"differ, see {path}); give the same ones or a new --out")
        return
    out.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(settings, indent=2) + "\n")
    os.replace(tmp, path)


def evaluate_pick_sets(policy=None, *, out, sets=None, episodes: int = 50, seed: int = 0, jobs: int = 1,
                       resume: bool = False, progress: bool = True, command: list[str] | None = None,
                       report_command: str | None = None, echo=print, **eval_high_settings):
    """``policy`` (a checkpoint or None: the shipped one; or ``baseline=`` in the settings) on each of ``sets``
    (default the pick table's 12), ``episodes`` each at ``seed``, into ``out``; returns the pick table
    (``hingelab.analysis.pick_table.write_picks``) it writes to ``out/picks.md`` and ``picks.csv``."""
    from hingelab.analysis.pick_table import write_picks

    if jobs < 1:
        raise ConfigError(f"--jobs {jobs}: give 1 or more")
    out = Path(out)
    sets = parse_sets(sets)
    settings = {"policy": None if policy is None else str(policy), "episodes": episodes, "seed": seed,
                "sets": [f"{shape}:{size:g}" for shape, size in sets],
                **{k: v for k, v in sorted(eval_high_settings.items())}}
    _record(out, settings, resume)
    jobs_todo = []
    for shape, size in sets:
        folder = set_folder(out, shape, size)
        if _finished(folder):
            echo(f"{folder.name}: done before, kept")
            continue
        jobs_todo.append({"policy": policy, "out": str(folder), "object": shape, "size": size, "episodes": episodes,
                          "seed": seed, "command": command, "progress": progress and jobs == 1,
                          **eval_high_settings})
    if jobs == 1 or len(jobs_todo) <= 1:
        for job in jobs_todo:
            echo(_evaluate_one(job))
    else:
        from hingelab.workers.local_pool import map_unordered

        for summary in map_unordered(_evaluate_one, [{**job, "single_thread": True} for job in jobs_todo],
                                     min(jobs, len(jobs_todo))):
            echo(summary)
    folders = [set_folder(out, shape, size) for shape, size in sets]
    return write_picks(folders, out, report_command or f"hingelab eval picks --out {out}")


__all__ = ["PICKS_FILE", "evaluate_pick_sets", "parse_sets", "set_folder"]
