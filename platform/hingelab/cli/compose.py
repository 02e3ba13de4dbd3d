"""``hingelab compose low``: one low-level policy from experts that each serve a band of goal openings.

Writes a manifest (``hingelab.policies.goal_experts``) that ``hingelab eval low``, ToolPick-v0's
``low_level=`` and ``PolicyLowLevel`` take wherever they take a checkpoint.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from hingelab.errors import ConfigError
from hingelab.out_dir import check_out_file
from hingelab.paths import refuse_to_replace_shipped


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("compose", help="combine trained policies into one",
                              description="Combine trained policies into one policy file.")
    what = p.add_subparsers(title="policies", metavar="WHAT", required=True)
    low = what.add_parser(
        "low", help="low-level experts, each for a band of goal openings",
        description="Write a goal-region experts manifest: the goal latent's opening (the shipped "
                    "encoder's calibration, nearest point of the curve) picks which low-level checkpoint "
                    "acts. Give the experts from the closed end up, each but the last with the largest "
                    "opening it serves: --expert closed.zip:0.10 --expert rest.zip. Every checkpoint is "
                    "checked as `hingelab eval low` checks one (ToolShape-v0's spaces, the encoder's "
                    "latents) and recorded with its sha256.")
    low.add_argument("--expert", action="append", required=True, metavar="CHECKPOINT[:UP_TO_RAD]",
                     help="a model.zip (or run folder) from hingelab train low and the largest goal opening "
                          "(rad) it serves; repeat, closed end first; the last has no bound")
    low.add_argument("--out", type=Path, required=True,
                     help="manifest to write (.json; checkpoint paths are stored relative to its folder)")
    low.add_argument("--force", action="store_true",
                     help="replace an existing manifest under assets/ (the shipped low level) on purpose")
    low.set_defaults(func=run_low)


def parse_expert(text: str) -> tuple[Path, float | None]:
    """'path.zip:0.10' -> (path.zip, 0.10); 'path.zip' -> (path.zip, None)."""
    path, sep, bound = text.rpartition(":")
    if not sep:
        return Path(text), None
    try:
        value = float(bound)
    except ValueError:  # a ':' of the path itself
        return Path(text), None
    if not path:
        raise ConfigError(f"--expert {text!r} has no checkpoint before the ':'")
    return Path(path), value


def run_low(args: argparse.Namespace) -> int:
    from hingelab.policies.goal_experts import (  # on run: the parser stays light (hingelab.cli)
        load_experts,
        write_experts,
    )

    check_out_file(args.out)
    refuse_to_replace_shipped(args.out, args.force)
    experts = [parse_expert(text) for text in args.expert]
    if any(bound is None for _, bound in experts[:-1]) or experts[-1][1] is not None:
        raise ConfigError("give every --expert but the last an opening bound (CHECKPOINT:UP_TO_RAD), and the "
                          "last none (it serves the goals above)")
    if len(experts) < 2:
        raise ConfigError("give at least two --expert checkpoints")
    out = write_experts(args.out, experts)
    policy = load_experts(out)
    bands, low = [], "closed"
    for (path, bound) in experts:
        bands.append(f"{path} for goals from {low} to {'open' if bound is None else f'{bound:.3f} rad'}")
        low = f"{bound:.3f} rad" if bound is not None else low
    print(f"Wrote {out}: {len(policy.experts)} experts; " + "; ".join(bands) + ".")
    return 0
