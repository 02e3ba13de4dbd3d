"""``hingelab train WHAT``: train a learner from datasets.

One sub-subcommand per learner. ``LEARNERS`` maps a name to the function that adds its
sub-subcommand (``"module:function"``, imported on use), so a later learner (``low``,
``high``) is one entry here and one module of its own. Each run shows progress, logs
per-epoch metrics, writes a checkpoint that records its data, config, seed and code
version, and ends with a one-paragraph summary.
"""

from __future__ import annotations

import argparse
import importlib
from pathlib import Path

LEARNERS = {
    "encoder": "hingelab.cli.train:add_encoder_parser",
}


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "train",
        help="train the tool encoder or a policy from datasets",
        description=f"Train a learner from datasets. Learners: {', '.join(LEARNERS)}.",
    )
    learners = p.add_subparsers(title="learners", metavar="WHAT", required=True)
    for name, target in LEARNERS.items():
        module, function = target.split(":")
        getattr(importlib.import_module(module), function)(learners)


# ---------------------------------------------------------------------------- encoder
def add_encoder_parser(learners) -> None:
    from hingelab.perception.encoder import SHIPPED_CHECKPOINT, EncoderConfig
    from hingelab.perception.train_encoder import TrainEncoderConfig

    d = TrainEncoderConfig()
    p = learners.add_parser(
        "encoder",
        help="the PointNet VAE tool encoder, from a cloud dataset (hingelab generate clouds)",
        description="Register every cloud of the dataset, train the PointNet VAE (Chamfer + beta KL) on the "
                    "clouds in the tool frame, fit the latent <-> opening calibration and write a checkpoint.",
    )
    p.add_argument("--data", type=Path, required=True, help="a cloud dataset folder (hingelab generate clouds)")
    p.add_argument("--epochs", type=int, default=d.epochs, help=f"training epochs (default {d.epochs})")
    p.add_argument("--batch-size", type=int, default=d.batch_size, help=f"clouds per step (default {d.batch_size})")
    p.add_argument("--lr", type=float, default=d.learning_rate, help=f"Adam learning rate (default {d.learning_rate})")
    p.add_argument("--beta", type=float, default=EncoderConfig().beta,
                   help=f"KL weight of the VAE loss (default {EncoderConfig().beta})")
    p.add_argument("--seed", type=int, default=d.seed, help=f"seed of weights and batches (default {d.seed})")
    p.add_argument("--out", type=Path, default=SHIPPED_CHECKPOINT,
                   help=f"checkpoint to write (default {SHIPPED_CHECKPOINT})")
    p.add_argument("--no-progress", action="store_true", help="log one JSON line per epoch instead of a bar")
    p.set_defaults(func=run_encoder)


def run_encoder(args: argparse.Namespace) -> int:
    from hingelab.perception.encoder import EncoderConfig
    from hingelab.perception.train_encoder import TrainEncoderConfig, train_encoder

    config = TrainEncoderConfig(epochs=args.epochs, batch_size=args.batch_size, learning_rate=args.lr, seed=args.seed)
    _, m = train_encoder(args.data, args.out, config, EncoderConfig(beta=args.beta), progress=not args.no_progress)
    print(f"Trained the tool encoder for {config.epochs} epochs on {m['train_clouds']} clouds of {args.data} "
          f"(seed {config.seed}) in {m['wall_time_s'] / 60:.1f} min and wrote {args.out}. On {m['val_clouds']} "
          f"held-out clouds: Chamfer {m['val_chamfer_mm2']:.2f} mm^2, calibration R^2 {m['r2_opening_val']:.3f} "
          f"for the opening (mean error {m['mae_opening_rad_val'] * 1000:.1f} mrad) and {m['r2_gap_val']:.3f} "
          f"for the tip gap (mean error {m['mae_gap_mm_val']:.2f} mm). Per-epoch metrics are in the checkpoint "
          "(`history`); load it with hingelab.perception.encoder.load_encoder.")
    return 0
