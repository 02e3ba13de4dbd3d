"""The learners, registered by name for each level they train (``@register_learner``).

A learner is one folder under ``hingelab/learners/`` (or a package of its own, named in the
``hingelab.learners`` entry-point group) whose ``__init__`` registers a class with:

* ``name`` (what ``--learner`` takes) and ``level`` (``low``, ``high`` or ``flat``: the command
  ``hingelab train LEVEL``), ``help`` (one line) and ``description`` (the command's ``--help`` text);
* ``config_class``: a frozen dataclass of ``hingelab.training.run_config.option`` fields, composed of
  the parts in ``hingelab.training.config_parts`` and its own fields: every field is a flag of
  ``hingelab train LEVEL --learner NAME`` and is saved in ``RUNDIR/config.json``;
* ``default_out``: the run folder when ``--out`` is not given (``{SEED}`` is the run's seed);
* ``train(config, run_dir, resume, progress, name) -> dict``: the run; the dict holds at least
  ``run_dir``, ``wall_time_s`` and ``last_evaluation``;
* ``summary(result, config, run_dir) -> str``: the paragraph the command prints at the end.

``discover()`` imports the built-in learners (every sub-package here) and the entry points, so adding
a learner edits no other file.
"""

from __future__ import annotations

import argparse
import importlib
import json
import pkgutil
from importlib.metadata import entry_points
from pathlib import Path

from hingelab.errors import ConfigError
from hingelab.training.run_config import add_config_arguments, add_run_arguments

LEVELS = ("low", "high", "flat")
DEFAULT_LEARNER = "sac"
ENTRY_POINT_GROUP = "hingelab.learners"
_LEARNERS: dict[tuple[str, str], type] = {}
_discovered = False


def register_learner(cls: type) -> type:
    """Class decorator: ``cls`` trains level ``cls.level`` under ``--learner cls.name``."""
    missing = [a for a in ("name", "level", "config_class", "help", "default_out", "train", "summary")
               if not hasattr(cls, a)]
    if missing:
        raise TypeError(f"learner {cls.__name__} lacks {', '.join(missing)} (hingelab.learners.registry)")
    if cls.level not in LEVELS:
        raise TypeError(f"learner {cls.__name__}: level {cls.level!r} is not one of {LEVELS}")
    _LEARNERS[(cls.level, cls.name)] = cls
    return cls


def discover() -> None:
    """Import every learner package under ``hingelab.learners`` and the ``hingelab.learners`` entry points
    (once): their registrations run on import."""
    global _discovered
    if _discovered:
        return
    _discovered = True
    for module in pkgutil.iter_modules([str(Path(__file__).parent)]):
        if module.ispkg:
            importlib.import_module(f"{__package__}.{module.name}")
    for entry in entry_points(group=ENTRY_POINT_GROUP):
        entry.load()


def learners(level: str) -> dict[str, type]:
    """The learners of ``level`` by name, the default first."""
    discover()
    found = {name: cls for (lvl, name), cls in _LEARNERS.items() if lvl == level}
    return dict(sorted(found.items(), key=lambda item: (item[0] != DEFAULT_LEARNER, item[0])))


def learner(level: str, name: str) -> type:
    found = learners(level)
    if name not in found:
        raise ConfigError(f"no learner {name!r} for train {level}; the learners: {', '.join(found) or 'none'}")
    return found[name]


def add_learner_arguments(parser, level: str, chosen: type) -> None:
    """``--learner`` (the names of ``level``'s learners), ``chosen``'s config fields and the run folder's flags:
    the flags of ``hingelab train LEVEL --learner NAME`` (the CLI's and a sweep's check of its arguments)."""
    found = learners(level)
    parser.add_argument("--learner", choices=tuple(found), default=chosen.name,
                        help=f"the learner ({'; '.join(f'{n}: {cls.help}' for n, cls in found.items())}); the "
                             f"flags below are {chosen.name}'s (default {DEFAULT_LEARNER})")
    add_config_arguments(parser, chosen.config_class)
    add_run_arguments(parser, chosen.default_out)


def learner_parser(level: str, name: str) -> argparse.ArgumentParser:
    """A parser of ``hingelab train LEVEL --learner NAME``'s flags, on its own."""
    parser = argparse.ArgumentParser(prog=f"hingelab train {level}", add_help=False)
    add_learner_arguments(parser, level, learner(level, name))
    return parser


def run_learner(run_dir) -> str | None:
    """The learner a run folder records (``config.json``: ``learner`` beside the config, or inside it as
    older runs wrote it), None when the folder has no readable config."""
    path = Path(run_dir) / "config.json"
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return doc.get("learner") or (doc.get("config") or {}).get("learner") or DEFAULT_LEARNER


__all__ = ["register_learner", "discover", "learners", "learner", "run_learner", "add_learner_arguments",
           "learner_parser", "LEVELS", "DEFAULT_LEARNER"]
