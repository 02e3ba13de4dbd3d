"""``hingelab train WHAT``: train the tool encoder, or a policy with one of the registered learners.

``train encoder`` trains the PointNet VAE from a cloud dataset. ``train low|high|flat [--learner NAME]``
trains a policy with a learner of ``hingelab.learners`` (the default ``sac``); the flags are the chosen
learner's config fields (``--learner`` is read from the command line before the parser is built, so
``--help`` lists what applies to it), the run folder's flags are every learner's. A ``--resume`` without
``--learner`` continues with the learner the run folder records.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from hingelab import paths
from hingelab.arguments import check_processes, finite_float
from hingelab.bounded_reads import resolved_input
from hingelab.cli.options import add_max_mesh_mb
from hingelab.errors import ConfigError
from hingelab.folder_lock import folder_lock
from hingelab.learners import registry
from hingelab.out_dir import RUN, check_out, check_out_file
from hingelab.paths import refuse_to_replace_shipped
from hingelab.perception.encoder_config import EncoderConfig, TrainEncoderConfig
from hingelab.seeds import seed_argument
from hingelab.training.run_config import config_from_args, given_settings


def add_parser(subparsers, argv: list[str] = ()) -> None:
    p = subparsers.add_parser(
        "train",
        help="train the tool encoder or a policy from datasets",
        description="Train the tool encoder, or a policy with a registered learner: "
                    + "; ".join(f"{level}: {', '.join(registry.learners(level))}" for level in registry.LEVELS) + ".",
    )
    levels = p.add_subparsers(title="what to train", metavar="WHAT", required=True)
    add_encoder_parser(levels)
    for level in registry.LEVELS:
        add_policy_parser(levels, level, chosen_learner(list(argv), level))


def chosen_learner(argv: list[str], level: str) -> str:
    """The ``--learner`` of ``train LEVEL`` on this command line; on a ``--resume`` without it, the learner
    the ``--out`` run folder records; else the default."""
    if argv[:2] != ["train", level]:  # the verb is the command line's first word (hingelab has no global flag)
        return registry.DEFAULT_LEARNER
    args = argv[2:]
    for i, token in enumerate(args):
        if token == "--learner" and i + 1 < len(args):
            return args[i + 1]
        if token.startswith("--learner="):
            return token.split("=", 1)[1]
    if "--resume" in args:
        for i, token in enumerate(args):
            out = args[i + 1] if token == "--out" and i + 1 < len(args) else (
                token.split("=", 1)[1] if token.startswith("--out=") else None)
            if out:
                return registry.run_learner(out) or registry.DEFAULT_LEARNER
    return registry.DEFAULT_LEARNER


def add_policy_parser(levels, level: str, name: str) -> None:
    found = registry.learners(level)
    learner = found.get(name) or found[registry.DEFAULT_LEARNER]
    p = levels.add_parser(level, help=found[registry.DEFAULT_LEARNER].help, description=learner.description)
    registry.add_learner_arguments(p, level, learner)
    add_max_mesh_mb(p)
    p.set_defaults(func=run_policy, level=level, learner_class=learner)


def run_policy(args: argparse.Namespace) -> int:

    learner = args.learner_class
    if args.learner != learner.name:  # argparse took a --learner the pre-scan did not see (an abbreviation)
        raise ConfigError(f"--learner {args.learner}: write it out as --learner {args.learner} (not abbreviated)")
    # paths the run records: absolute, so the run folder says where its inputs were wherever it is run
    if getattr(args, "init_from", ""):
        args.init_from = str(resolved_input(args.init_from, "--init-from"))
    if hasattr(args, "from_datasets"):
        args.from_datasets = tuple(str(resolved_input(p, "--from")) if args.level != "low" else str(p)
                                   for p in args.from_datasets)
    if getattr(args, "low_level", "none") not in ("policy", "privileged", "none"):
        args.low_level = str(resolved_input(args.low_level, "--low-level"))
    config = config_from_args(learner.config_class, args)
    if args.out is None:
        default = learner.default_out_for(config) if hasattr(learner, "default_out_for") else \
            learner.default_out.format(SEED=config.seed)
        out = paths.REPO_ROOT / default
    else:
        out = args.out
    refuse_to_replace_shipped(out, args.force)  # first: under assets/, --force is the fix to name
    check_out(out, RUN)
    if args.resume:
        from hingelab.training.run_folder import resumed_config  # on run: the parser stays light (hingelab.cli)

        recorded = registry.run_learner(out)
        if recorded is not None and recorded != learner.name:
            raise ConfigError(f"{out} is a run of --learner {recorded}, not {learner.name}: resume it with "
                              f"--learner {recorded}")
        config = resumed_config(out, config, given_settings(learner.config_class, args))
    if getattr(config, "subprocess_envs", False):  # one process per env: a simulator each
        check_processes(config.n_envs, "--envs", args.allow_oversubscribe)
    if getattr(config, "jobs", 1) > 1:  # worker processes (phase clone, DAgger): a simulator each
        check_processes(config.jobs, "--jobs", args.allow_oversubscribe)
    with folder_lock(out, args.argv):
        result = learner.train(config, out, resume=args.resume, progress=not args.no_progress, name=args.name)
    print(learner.summary(result, config, out))
    return 0


# ---------------------------------------------------------------------------- encoder
def add_encoder_parser(learners) -> None:

    d = TrainEncoderConfig()
    p = learners.add_parser(
        "encoder",
        help="the PointNet VAE tool encoder, from a cloud dataset (hingelab generate clouds)",
        description="Register every cloud of the dataset, train the PointNet VAE (Chamfer + beta KL) on the "
                    "clouds in the tool frame, fit the latent <-> opening calibration and write a checkpoint.",
    )
    p.add_argument("--data", type=Path,
                   help="a cloud dataset folder (hingelab generate clouds); not with --recalibrate-curve")
    p.add_argument("--epochs", type=int, default=d.epochs, help=f"training epochs (default {d.epochs})")
    p.add_argument("--batch-size", type=int, default=d.batch_size, help=f"clouds per step (default {d.batch_size})")
    p.add_argument("--lr", type=finite_float, default=d.learning_rate,
                   help=f"Adam learning rate (default {d.learning_rate})")
    p.add_argument("--beta", type=finite_float, default=EncoderConfig().beta,
                   help=f"KL weight of the VAE loss (default {EncoderConfig().beta})")
    p.add_argument("--seed", type=seed_argument, default=d.seed, help=f"seed of weights and batches (default {d.seed})")
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
    from hingelab.perception.train_encoder import (  # on run: the parser stays light (hingelab.cli)
        recalibrate_encoder,
        train_encoder,
    )

    if args.out is not None:
        check_out_file(args.out)
    if args.recalibrate or args.recalibrate_curve:
        if args.out is None:
            raise ConfigError("--recalibrate and --recalibrate-curve rewrite a checkpoint: name it with --out CKPT")
        refuse_to_replace_shipped(args.out, args.force)
    if args.recalibrate_curve:
        return run_curve_recalibration(args)
    if args.data is None:
        raise ConfigError("hingelab train encoder needs --data DATASET (a cloud dataset: hingelab generate clouds)")
    if args.recalibrate:

        encoder, m = recalibrate_encoder(args.data, args.out, progress=not args.no_progress)
        print(f"Fitted the latent -> opening reader of {args.out} on {args.data} in {m['wall_time_s']:.0f} s: "
              f"R^2 {m['reader_r2_opening_train']:.4f} on the training clouds, {m['r2_opening_val']:.4f} on the "
              f"held-out ones (mean error {m['mae_opening_rad_val'] * 1000:.1f} mrad); fingerprint "
              f"{encoder.fingerprint} (unchanged).")
        return 0
    args.out = args.out or paths.REPO_ROOT / "runs" / f"encoder_seed{args.seed}" / "encoder.pt"
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
    from hingelab.perception.sim_calibration import recalibrate_curve  # on run: the parser stays light (hingelab.cli)

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
