"""The numbers every command takes, checked at the door: argparse ``type=`` functions and the cap on processes.

A value out of range is refused before anything runs or is written (argparse prints the command's usage and
one error line): seeds in [0, 2**32) (``hingelab.seeds.seed_argument``), floats finite (no nan, no inf), counts
of CPUs, workers and envs at least 1, and parallel processes at most the cores this process may use.
"""

from __future__ import annotations

import argparse
import math
import os

from hingelab.errors import ConfigError


def finite_float(text: str) -> float:
    """A float flag's value: any finite number (``nan`` and ``inf`` parse as floats but mean nothing here)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
    return value


def positive_int(text: str) -> int:
    """A count of things that run (CPUs, workers, envs): an integer of at least 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{value} is not a count: give at least 1")
    return value


def available_cores() -> int:
    """The cores this process may run on (its affinity where the OS has one, else every core)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # macOS and Windows have no affinity call
        return os.cpu_count() or 1


def check_processes(count: int, flag: str, allow_oversubscribe: bool = False) -> None:
    """Refuse ``count`` parallel processes (``--workers``, ``--envs``, ``--jobs``) beyond the available cores in one
    line: each holds a simulator and its libraries (about 0.5 GB), and more of them than cores only share the
    cores."""
    cores = available_cores()
    if count > cores and not allow_oversubscribe:
        raise ConfigError(f"{flag} {count}: this machine gives the run {cores} core(s); give at most {cores}, or "
                          "--allow-oversubscribe to start more processes than cores on purpose")


def add_oversubscribe(p) -> None:
    """``--allow-oversubscribe``: more worker processes than cores, on purpose."""
    p.add_argument("--allow-oversubscribe", action="store_true",
                   help="allow more parallel processes (--workers, --envs, --jobs) than the cores this process may use "
                        "(each is a simulator of about 0.5 GB)")


__all__ = ["finite_float", "positive_int", "available_cores", "check_processes", "add_oversubscribe"]
