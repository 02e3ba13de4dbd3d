"""The sweep file of ``hingelab sweep``: a grid of seeds times conditions of one training command.

::

    [sweep]
    command = "train low"          # train low | train high | train flat
    seeds = [0, 1, 2]
    args = ["--steps", "30000"]    # given to every trial
    cpus_per_trial = 1             # torch threads and env workers follow it

    [conditions]                   # name = extra arguments
    effort = []
    no_effort = ["--no-effort"]

Trial ``<condition>_seed<S>`` runs ``hingelab <command> <args> <condition's args> --seed S --out
DIR/<condition>_seed<S> --name <condition>``, with ``--envs C --threads C`` (C = cpus_per_trial;
and ``--in-process`` at 1) unless the arguments set them. ``load_sweep`` checks every trial's command
line against the command's own parser, so a flag the command does not have, a bad value or a flag
the sweep sets itself is one ``ConfigError`` naming the file, before anything starts.
"""

from __future__ import annotations

import argparse
import re
import tomllib
from dataclasses import dataclass
from pathlib import Path

from hingelab.errors import ConfigError
from hingelab.learners import registry

COMMANDS = ("train low", "train high", "train flat")  # the SAC learners: each writes a resumable run folder
SWEEP_FLAGS = ("--seed", "--out", "--name", "--resume", "--no-progress")  # set by the sweep for each trial
NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")


@dataclass(frozen=True)
class Trial:
    condition: str
    seed: int
    argv: tuple[str, ...]  # the hingelab command line, without --out/--resume

    @property
    def name(self) -> str:
        return f"{self.condition}_seed{self.seed}"


@dataclass(frozen=True)
class SweepSpec:
    path: Path
    text: str
    command: str
    seeds: tuple[int, ...]
    args: tuple[str, ...]
    cpus_per_trial: int
    conditions: dict[str, tuple[str, ...]]

    def trials(self) -> list[Trial]:
        """Condition by condition, seed by seed (the file's order)."""
        return [Trial(c, s, self.trial_argv(c, s)) for c in self.conditions for s in self.seeds]

    def trial_argv(self, condition: str, seed: int) -> tuple[str, ...]:
        given = (*self.args, *self.conditions[condition])
        cpus = []
        if not _has(given, "--envs"):
            cpus += ["--envs", str(self.cpus_per_trial)]
        if not _has(given, "--threads"):
            cpus += ["--threads", str(self.cpus_per_trial)]
        if self.cpus_per_trial == 1 and not _has(given, "--in-process"):
            cpus += ["--in-process"]  # one core: the env steps in the trainer's process
        return (*self.command.split(), *given, *cpus, "--seed", str(seed), "--name", condition, "--no-progress")


def _has(args, flag: str) -> bool:
    return any(a == flag or a.startswith(flag + "=") for a in args)


def _fail(path: Path, message: str):
    raise ConfigError(f"sweep file {path}: {message}")


def _strings(path: Path, value, where: str) -> tuple[str, ...]:
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        _fail(path, f"{where} must be a list of strings, e.g. [\"--steps\", \"30000\"], not {value!r}")
    return tuple(value)


def load_sweep(path) -> SweepSpec:
    """The sweep file at ``path``, checked (see the module docstring)."""
    path = Path(path)
    try:
        text = path.read_text()
        doc = tomllib.loads(text)
    except OSError as exc:
        raise ConfigError(f"cannot read the sweep file {path}: {exc.strerror or exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"sweep file {path} is not TOML: {exc}") from exc
    sweep = doc.get("sweep")
    if not isinstance(sweep, dict):
        _fail(path, "no [sweep] table; it needs command, seeds and args (see `hingelab sweep --help`)")
    unknown = sorted(set(doc) - {"sweep", "conditions"}) + sorted(
        f"sweep.{k}" for k in set(sweep) - {"command", "seeds", "args", "cpus_per_trial"})
    if unknown:
        _fail(path, f"unknown key(s) {', '.join(unknown)}; the file has [sweep] (command, seeds, args, "
                    "cpus_per_trial) and [conditions]")
    command = " ".join(str(sweep.get("command", "")).split())
    if command not in COMMANDS:
        _fail(path, f"command {sweep.get('command')!r} is not a hingelab training command a sweep can run; "
                    f"use one of {', '.join(repr(c) for c in COMMANDS)}")
    seeds = sweep.get("seeds")
    if not isinstance(seeds, list) or not seeds or not all(isinstance(s, int) and not isinstance(s, bool)
                                                           and s >= 0 for s in seeds):
        _fail(path, f"seeds must be a non-empty list of integers >= 0, e.g. seeds = [0, 1, 2], not {seeds!r}")
    if len(set(seeds)) != len(seeds):
        _fail(path, f"seeds {seeds} repeat a seed; each seed once")
    args = _strings(path, sweep.get("args", []), "[sweep] args")
    cpus = sweep.get("cpus_per_trial", 1)
    if not isinstance(cpus, int) or isinstance(cpus, bool) or cpus < 1:
        _fail(path, f"cpus_per_trial must be an integer >= 1, not {cpus!r}")
    conditions = doc.get("conditions")
    if not isinstance(conditions, dict) or not conditions:
        _fail(path, "no [conditions] table; name at least one condition, e.g. baseline = []")
    checked = {}
    for name, extra in conditions.items():
        if not NAME.match(name):
            _fail(path, f"condition name {name!r} must be letters, digits, '_', '-' or '.' (it names run folders)")
        checked[name] = _strings(path, extra, f"condition {name}")
    spec = SweepSpec(path, text, command, tuple(seeds), args, cpus, checked)
    for condition in spec.conditions:
        given = (*args, *checked[condition])
        _check_arguments(path, _command_parser(path, command, given), command, condition, given,
                         spec.trial_argv(condition, spec.seeds[0]))
    return spec


class _ParseError(Exception):
    pass


def _command_parser(path: Path, command: str, given: tuple) -> argparse.ArgumentParser:
    """The flags of ``hingelab <command>`` for the learner the arguments name (``--learner``, else the
    default): built from that learner's config, as the command line builds them."""
    level = command.split()[1]
    name = registry.DEFAULT_LEARNER
    for i, token in enumerate(given):
        if token == "--learner" and i + 1 < len(given):
            name = given[i + 1]
        elif token.startswith("--learner="):
            name = token.split("=", 1)[1]
    try:
        return registry.learner_parser(level, name)
    except ConfigError as exc:
        _fail(path, str(exc))


def _check_arguments(path: Path, parser, command: str, condition: str, given: tuple, argv: tuple) -> None:
    where = f"condition {condition!r} (with [sweep] args)"
    taken = [a for a in given if a.split("=")[0] in SWEEP_FLAGS]
    if taken:
        _fail(path, f"{where} gives {', '.join(taken)}, which the sweep sets for every trial; leave them out")

    def refuse(message: str):
        raise _ParseError(message)

    error, parser.error = parser.error, refuse  # argparse would print usage and exit
    try:
        _, extra = parser.parse_known_args(list(argv[len(command.split()):]) + ["--out", "x"])
    except _ParseError as exc:
        _fail(path, f"{where}: `hingelab {command}` refuses it: {exc}")
    finally:
        parser.error = error
    if extra:
        _fail(path, f"{where} gives {' '.join(extra)}, which `hingelab {command}` does not have "
                    f"(see `hingelab {command} --help`)")


__all__ = ["COMMANDS", "SweepSpec", "Trial", "load_sweep"]
