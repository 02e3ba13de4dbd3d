"""``hingelab checkpoints convert``: older trusted checkpoints rewritten so they load without running code."""

from __future__ import annotations

import argparse
from pathlib import Path

from hingelab.errors import ConfigError
from hingelab.folder_lock import folder_lock


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("checkpoints", help="convert checkpoints to formats that load without running code",
                              description="Checkpoints load without unpickling anything but tensors and plain "
                                          "values (encoders with torch.load(weights_only=True); SAC zips without "
                                          "their cloudpickle entries).")
    verbs = p.add_subparsers(title="verbs", metavar="VERB", required=True)
    convert = verbs.add_parser(
        "convert", help="rewrite trusted checkpoints of an older hingelab with plain values only",
        description="Rewrite each encoder checkpoint (.pt) with tensors and plain values only, checking that its "
                    "fingerprint (what its latents mean) is unchanged; for a run folder, rewrite its pickled "
                    "resume checkpoints (state.pkl, replay_buffer.pkl) as state.json and replay_buffer.npz so "
                    "--resume can read them. Reading an old file runs its pickle: convert only files you trust. "
                    "SAC zips and phase clones (.zip) need no conversion: they are checked to load without "
                    "unpickling.")
    convert.add_argument("files", type=Path, nargs="*",
                         help="checkpoints or run folders to convert (default: the shipped encoder, "
                              "assets/checkpoints/encoder.pt)")
    convert.set_defaults(func=run_convert)


def run_convert(args: argparse.Namespace) -> int:
    from hingelab.perception.encoder import (  # on run: the parser stays light (hingelab.cli)
        SHIPPED_CHECKPOINT,
        convert_checkpoint,
    )
    from hingelab.policies.phase_clone import PhaseClone, is_phase_clone
    from hingelab.policies.sb3_zip import read_plain_data
    from hingelab.training.checkpoints import convert_pickled

    for path in args.files or [SHIPPED_CHECKPOINT]:
        if path.is_dir():

            with folder_lock(path, args.argv):
                rewritten = convert_pickled(path)
            print(f"{path}: {len(rewritten)} pickled checkpoint(s) rewritten as state.json and replay_buffer.npz"
                  if rewritten else f"{path}: no pickled checkpoints; nothing to convert.")
            continue
        if not path.is_file():
            raise ConfigError(f"{path} does not exist")
        if path.suffix == ".zip":

            if is_phase_clone(path):
                PhaseClone.load(path)
                print(f"{path}: a phase clone (JSON and plain arrays), read without unpickling; nothing to convert.")
                continue
            read_plain_data(path)
            print(f"{path}: a SAC zip, read without unpickling; nothing to convert.")
            continue
        fingerprint, rewritten = convert_checkpoint(path)
        state = "rewritten with plain values only" if rewritten else "already plain"
        print(f"{path}: {state}; fingerprint {fingerprint} unchanged.")
    return 0
