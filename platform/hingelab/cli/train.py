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

from hingelab.errors import ConfigError

LEARNERS = {
    "encoder": "hingelab.cli.train:add_encoder_parser",
    "low": "hingelab.cli.train:add_low_parser",
    "high": "hingelab.cli.train_high:add_high_parser",
    "flat": "hingelab.cli.train_high:add_flat_parser",
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
    from hingelab.perception.encoder import EncoderConfig
    from hingelab.perception.train_encoder import TrainEncoderConfig

    d = TrainEncoderConfig()
    p = learners.add_parser(
        "encoder",
        help="the PointNet VAE tool encoder, from a cloud dataset (hingelab generate clouds)",
        description="Register every cloud of the dataset, train the PointNet VAE (Chamfer + beta KL) on the "
                    "clouds in the tool frame, fit the latent <-> opening calibration and write a checkpoint.",
    )
    p.add_argument("--data", type=Path, help="a cloud dataset folder (hingelab generate clouds); not with --recalibrate-curve")
    p.add_argument("--epochs", type=int, default=d.epochs, help=f"training epochs (default {d.epochs})")
    p.add_argument("--batch-size", type=int, default=d.batch_size, help=f"clouds per step (default {d.batch_size})")
    p.add_argument("--lr", type=float, default=d.learning_rate, help=f"Adam learning rate (default {d.learning_rate})")
    p.add_argument("--beta", type=float, default=EncoderConfig().beta,
                   help=f"KL weight of the VAE loss (default {EncoderConfig().beta})")
    p.add_argument("--seed", type=int, default=d.seed, help=f"seed of weights and batches (default {d.seed})")
    p.add_argument("--threads", type=int, default=d.threads,
                   help=f"torch CPU threads (default {d.threads}; 1 to train two encoders side by side)")
    p.add_argument("--out", type=Path, default=None,
                   help="checkpoint to write (default runs/encoder_seed{SEED}/encoder.pt); with --recalibrate or "
                        "--recalibrate-curve, the checkpoint to rewrite (required)")
    p.add_argument("--force", action="store_true",
                   help="replace an existing checkpoint, e.g. the shipped assets/checkpoints/encoder.pt "
                        "(every shipped policy is bound to the shipped encoder: replace it only on purpose)")
    p.add_argument("--no-progress", action="store_true", help="log one JSON line per epoch instead of a bar")
    p.add_argument("--recalibrate", action="store_true",
                   help="do not train: fit the latent -> opening reader of the checkpoint --out on the training "
                        "split of --data (the dataset it was trained on) and rewrite it; weights, calibration "
                        "curve and fingerprint stay")
    p.add_argument("--recalibrate-curve", action="store_true",
                   help="do not train: refit the calibration curve and reader of the checkpoint --out on the "
                        "latents the envs perceive (tracked hinge sweeps of 3 mm clouds; no --data) and rewrite "
                        "it; the weights stay, the fingerprint changes, and low-level policies trained beside "
                        "the old one still load")
    p.add_argument("--sweeps", type=int, default=40,
                   help="with --recalibrate-curve: hinge sweeps to fit on, and as many more to check on (default 40)")
    p.set_defaults(func=run_encoder)


def run_encoder(args: argparse.Namespace) -> int:
    from hingelab.paths import REPO_ROOT, refuse_to_replace_shipped
    from hingelab.perception.encoder import EncoderConfig
    from hingelab.perception.train_encoder import TrainEncoderConfig, train_encoder

    if args.recalibrate or args.recalibrate_curve:
        if args.out is None:
            raise ConfigError("--recalibrate and --recalibrate-curve rewrite a checkpoint: name it with --out CKPT")
        refuse_to_replace_shipped(args.out, args.force)
    if args.recalibrate_curve:
        return run_curve_recalibration(args)
    if args.data is None:
        raise ConfigError("hingelab train encoder needs --data DATASET (a cloud dataset: hingelab generate clouds)")
    if args.recalibrate:
        from hingelab.perception.train_encoder import recalibrate_encoder

        encoder, m = recalibrate_encoder(args.data, args.out, progress=not args.no_progress)
        print(f"Fitted the latent -> opening reader of {args.out} on {args.data} in {m['wall_time_s']:.0f} s: "
              f"R^2 {m['reader_r2_opening_train']:.4f} on the training clouds, {m['r2_opening_val']:.4f} on the "
              f"held-out ones (mean error {m['mae_opening_rad_val'] * 1000:.1f} mrad); fingerprint "
              f"{encoder.fingerprint} (unchanged).")
        return 0
    args.out = args.out or REPO_ROOT / "runs" / f"encoder_seed{args.seed}" / "encoder.pt"
    refuse_to_replace_shipped(args.out, args.force)
    if args.out.exists() and not args.force:
        raise ConfigError(f"{args.out} exists: give --out a new checkpoint path, or --force to replace it")
    config = TrainEncoderConfig(epochs=args.epochs, batch_size=args.batch_size, learning_rate=args.lr, seed=args.seed,
                                threads=args.threads)
    _, m = train_encoder(args.data, args.out, config, EncoderConfig(beta=args.beta), progress=not args.no_progress)
    print(f"Trained the tool encoder for {config.epochs} epochs on {m['train_clouds']} clouds of {args.data} "
          f"(seed {config.seed}) in {m['wall_time_s'] / 60:.1f} min and wrote {args.out}. On {m['val_clouds']} "
          f"held-out clouds: Chamfer {m['val_chamfer_mm2']:.2f} mm^2, calibration R^2 {m['r2_opening_val']:.3f} "
          f"for the opening (mean error {m['mae_opening_rad_val'] * 1000:.1f} mrad) and {m['r2_gap_val']:.3f} "
          f"for the tip gap (mean error {m['mae_gap_mm_val']:.2f} mm). Per-epoch metrics are in the checkpoint "
          "(`history`); load it with hingelab.perception.encoder.load_encoder.")
    return 0


def run_curve_recalibration(args: argparse.Namespace) -> int:
    from hingelab.perception.sim_calibration import recalibrate_curve

    encoder, m = recalibrate_curve(args.out, sweeps=args.sweeps, seed=args.seed, progress=not args.no_progress)
    before = ", ".join(f"{r['band_rad']} rad {r['offset']:.3f}" for r in m["offsets_before"])
    after = ", ".join(f"{r['offset']:.3f}" for r in m["offsets_after"])
    print(f"Refitted the calibration curve of {args.out} on {m['latents']} tracked latents ({args.sweeps} sweeps, "
          f"seed {args.seed}) in {m['wall_time_s']:.0f} s. Held-out sweeps, distance of the mean latent from the "
          f"curve per opening band: before {before}; after {after}. Opening R^2 {m['r2_opening_before']:.4f} -> "
          f"{m['r2_opening_after']:.4f}; ToolShape-v0's success threshold {m['success_threshold_before']:.4f} -> "
          f"{m['success_threshold_after']:.4f}. Fingerprint {m['fingerprint_before']} -> {encoder.fingerprint} "
          "(policies trained beside the old one still load).")
    return 0


# ---------------------------------------------------------------------------- low
def add_run_arguments(p, default_out: str) -> None:
    """The flags every SAC learner's command has besides its config's."""
    p.add_argument("--out", type=Path, default=None,
                   help=f"run folder (default {default_out}); never under assets/ without --force")
    p.add_argument("--force", action="store_true", help="allow a run folder that replaces files under assets/")
    p.add_argument("--resume", action="store_true",
                   help="continue the run in --out from its last checkpoint (its saved config is kept; "
                        "--steps may raise the budget)")
    p.add_argument("--name", default=None, help="curve label in reports (default: the run folder's name)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def add_low_parser(learners) -> None:
    from hingelab.learning.low_level_config import LowLevelTrainConfig
    from hingelab.learning.run_config import add_config_arguments

    p = learners.add_parser(
        "low",
        help="the low-level policy: SAC shaping the tweezer to latent goals (ToolShape-v0)",
        description="Train the goal-conditioned low-level SAC policy on hingelab/ToolShape-v0. Every training "
                    "rollout is written as MCAP episodes into RUNDIR/dataset; evaluations on fixed held-out "
                    "goals go to RUNDIR/metrics.csv (hingelab report RUNDIR draws the curves); checkpoints "
                    "with the replay buffer go to RUNDIR/checkpoints (continue with --resume). All settings "
                    "are saved in RUNDIR/config.json; every one of them is a flag below.",
    )
    add_config_arguments(p, LowLevelTrainConfig)
    add_run_arguments(p, "runs/low_seed{SEED}[_no_effort]")
    p.set_defaults(func=run_low)


def run_low(args: argparse.Namespace) -> int:
    from hingelab.learning.low_level_config import LowLevelTrainConfig
    from hingelab.learning.run_config import config_from_args, given_settings
    from hingelab.learning.run_folder import resumed_config
    from hingelab.learning.train_low import train_low
    from hingelab.paths import REPO_ROOT, refuse_to_replace_shipped

    if getattr(args, "init_from", ""):  # the run folder records where it started from, wherever it is run
        args.init_from = str(Path(args.init_from).resolve())
    if hasattr(args, "from_datasets"):
        args.from_datasets = tuple(str(p) for p in args.from_datasets)
    config = config_from_args(LowLevelTrainConfig, args)
    out = args.out or REPO_ROOT / "runs" / f"low_seed{config.seed}{'' if config.use_effort else '_no_effort'}"
    refuse_to_replace_shipped(out, args.force)
    if args.resume:
        config = resumed_config(out, config, given_settings(LowLevelTrainConfig, args))
    s = train_low(config, out, resume=args.resume, progress=not args.no_progress, name=args.name)
    last, best = s["last_evaluation"], s["best"]
    prefill = ""
    if s["prefill"]:
        pf = s["prefill"]
        prefill = (f" The replay buffer was pre-filled with {pf['transitions']} transitions from {pf['episodes']} "
                   f"episodes at {pf['transitions_per_s']:.0f} transitions/s.")
    print(f"Trained the low-level policy to {s['env_steps']} env steps ({s['updates']} updates) in "
          f"{s['wall_time_s'] / 60:.1f} min.{prefill} Last evaluation: success {float(last.get('success_rate', 0)):.2f} "
          f"on {s['eval_goals']} held-out reachable goals, final latent distance "
          f"{float(last.get('final_latent_distance', 0)):.3f}, max tool drift "
          f"{float(last.get('tool_drift_mm_max', 0)):.1f} mm. Best: success {best['success_rate']:.2f} at "
          f"{best.get('env_steps', '?')} steps ({out}/best_model.zip). Curves: hingelab report {out}; "
          f"rollouts: {out}/dataset.")
    return 0
