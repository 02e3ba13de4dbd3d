"""Flags several commands share."""

from __future__ import annotations


def add_on_corrupt(p) -> None:
    """``--on-corrupt stop|skip``: what a command does with episode files it cannot read (``main`` applies it
    to every dataset the command opens, through ``hingelab.episodes.dataset.corrupt_policy``)."""
    p.add_argument("--on-corrupt", choices=("stop", "skip"), default="stop",
                   help="episode files that cannot be read (corrupt, cut off): stop (the default) names them all "
                        "and ends; skip leaves them out and says how many")
