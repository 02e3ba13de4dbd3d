"""Flags several commands share."""

from __future__ import annotations

from hingelab.cli.names import OBJECT_PERCEPTIONS


def add_on_corrupt(p) -> None:
    """``--on-corrupt stop|skip``: what a command does with episode files it cannot read (``main`` applies it
    to every dataset the command opens, through ``hingelab.episodes.dataset.corrupt_policy``)."""
    p.add_argument("--on-corrupt", choices=("stop", "skip"), default="stop",
                   help="episode files that cannot be read (corrupt, cut off): stop (the default) names them all "
                        "and ends; skip leaves them out and says how many")


def add_ray_argument(p) -> None:
    """``--ray [ADDR]``: episodes as Ray tasks, on a local one-node Ray or the cluster at ADDR."""
    p.add_argument("--ray", nargs="?", const="local", default=None, metavar="ADDR",
                   help="run the episodes as Ray tasks that write into --out (shared storage on a cluster): "
                        "on a local one-node Ray (no ADDR; --workers CPUs if given, else every core) or on the "
                        "running cluster at ADDR (`ray start --head` prints it); same seed, same episodes as "
                        "local workers")


def add_object_perception(p, needs: str) -> None:
    """``--object-perception NAME``: the object's true centre with 2 mm noise, or a camera object estimator
    (checked by the library, so a bad name is one line); ``needs`` says what the estimators need."""
    p.add_argument("--object-perception", default="truth", metavar="NAME",
                   help=f"where the object's position and extent come from: {', '.join(OBJECT_PERCEPTIONS)}; truth "
                        "(default) is the true centre with 2 mm noise, the others estimate it from the depth camera's "
                        f"frame each step (centroid: the paper's; hingelab.perception.object_estimate){needs}")
