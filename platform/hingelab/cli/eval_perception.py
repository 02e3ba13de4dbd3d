"""``hingelab eval perception``: the camera's perception against the synthesized clouds, same poses.

Writes into ``--out``: ``gap.csv`` (per perception: opening R^2 and error, tracking errors,
frames without a cloud), ``gap_steps.csv`` (every scored step), ``gap.json`` (the settings
and the code version) and ``camera_frame.png`` (one rendered depth frame, its tool mask, and
the camera's 256-point cloud over the synthesized cloud of the same pose).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from hingelab.errors import ConfigError
from hingelab.json_text import strict_dumps
from hingelab.out_dir import REPORT, check_out
from hingelab.provenance import code_version, require_clean_for
from hingelab.seeds import seed_argument


def add_parser(what) -> None:
    p = what.add_parser(
        "perception", help="camera perception against synthesized clouds (the sim-to-real gap)",
        description="Open and close the tweezer in the hand along the grasp synergy and perceive every step "
                    "twice: from synthesized clouds (the paper's training clouds) and from the rendered depth "
                    "camera through the camera cloud pipeline. Reports the encoder's opening R^2 and the "
                    "tracking error against the simulator's truth for both, and draws one camera frame.")
    p.add_argument("--episodes", type=int, default=8, help="episodes (default 8)")
    p.add_argument("--steps", type=int, default=100, help="control steps per episode (default 100, 5 s)")
    p.add_argument("--seed", type=seed_argument, default=0, help="seed of the episodes (default 0)")
    p.add_argument("--out", type=Path, required=True,
                   help="folder for gap.csv, gap_steps.csv, gap.json, camera_frame.png")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--allow-dirty", action="store_true",
                   help="write under analysis/ from uncommitted code (the result then names no commit)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from hingelab.perception.camera_gap import (  # on run: the parser stays light (hingelab.cli)
        GapConfig,
        run_gap,
        summarize,
    )
    from hingelab.perception.clouds import CloudRealism, CloudSynthesizer

    check_out(args.out, REPORT)
    if args.episodes < 1 or args.steps <= GapConfig.warmup_steps:
        raise ConfigError(f"--episodes must be >= 1 and --steps > {GapConfig.warmup_steps}")
    require_clean_for(args.out, args.allow_dirty, "hingelab eval perception")
    config = GapConfig(episodes=args.episodes, steps=args.steps, seed=args.seed)
    snapshot = {}

    def keep_frame(episode, step, sim, perceptions):
        if episode == 0 and step == config.steps // 2:  # mid-episode: tracking has settled
            snapshot["frame"] = perceptions["camera"].camera.frame
            snapshot["camera"] = perceptions["camera"].cloud.copy()
            # the synthesized cloud of this pose without the per-episode pose error: the same pose, its noise
            realism = CloudRealism(max_offset_m=0.0, max_angle_rad=0.0)
            snapshot["synthesized"] = CloudSynthesizer(realism=realism).from_sim(sim.model, sim.data)
            snapshot["opening"] = sim.reader.read(sim.data).hinge_angle

    rows = run_gap(config, progress=not args.no_progress, frame_hook=keep_frame)
    summary = summarize(rows)
    args.out.mkdir(parents=True, exist_ok=True)
    rows.to_csv(args.out / "gap_steps.csv", index=False)
    summary.to_csv(args.out / "gap.csv", index=False)
    (args.out / "gap.json").write_text(strict_dumps({
        "made_by": "hingelab eval perception", "episodes": config.episodes, "steps": config.steps,
        "seed": config.seed, "warmup_steps": config.warmup_steps, **code_version()},
        args.out / "gap.json", indent=1) + "\n")
    if snapshot:
        draw_frame(snapshot, args.out / "camera_frame.png")
    print(summary.round(4).to_string(index=False))
    by = summary.set_index("perception")
    print(f"\nOpening R^2 {by.loc['camera', 'opening_r2']:.3f} on camera clouds against "
          f"{by.loc['synthesized', 'opening_r2']:.3f} on synthesized ones ({len(rows) // 2} steps each, seed "
          f"{config.seed}); tracked position error median {by.loc['camera', 'position_error_mm_median']:.1f} mm "
          f"against {by.loc['synthesized', 'position_error_mm_median']:.1f} mm; "
          f"{100 * by.loc['camera', 'flagged_share']:.1f}% of camera frames gave no cloud. Written to {args.out}.")
    return 0


def draw_frame(snapshot: dict, path: Path) -> None:
    """Depth (m), tool mask, and the two clouds (hand_base, two views) side by side."""
    import matplotlib  # slow to import, and only --frame draws: loaded here, its backend set first

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np  # on run: the parser stays light (hingelab.cli)

    frame = snapshot["frame"]
    mask = frame.tool_mask
    rows, cols = np.nonzero(mask)
    pad = 60
    r0, r1 = max(rows.min() - pad, 0), min(rows.max() + pad, mask.shape[0])
    c0, c1 = max(cols.min() - pad, 0), min(cols.max() + pad, mask.shape[1])
    fig, axes = plt.subplots(1, 4, figsize=(17, 4.6))
    depth = np.where(frame.depth > 0, frame.depth, np.nan)
    im = axes[0].imshow(depth, cmap="viridis")
    axes[0].set_title(f"depth ({frame.intrinsics.width}x{frame.intrinsics.height}, m; white: no return)")
    fig.colorbar(im, ax=axes[0], fraction=0.04)
    axes[1].imshow(depth[r0:r1, c0:c1], cmap="viridis")
    axes[1].contour(mask[r0:r1, c0:c1], levels=[0.5], colors="red", linewidths=0.8)
    axes[1].set_title("close-up, tool mask (red) from segmentation")
    for ax, (i, j), label in ((axes[2], (0, 1), "x"), (axes[3], (0, 2), "x")):
        synth, cam = snapshot["synthesized"], snapshot["camera"]
        ax.scatter(synth[:, i] * 1000, synth[:, j] * 1000, s=6, c="0.6", label="synthesized (256, no pose error)")
        ax.scatter(cam[:, i] * 1000, cam[:, j] * 1000, s=6, c="tab:red", label="camera pipeline (256)")
        ax.set_xlabel(f"hand_base {'xyz'[i]} (mm)")
        ax.set_ylabel(f"hand_base {'xyz'[j]} (mm)")
        ax.set_aspect("equal")
    axes[2].set_title(f"clouds, same pose (opening {snapshot['opening']:.3f} rad)")
    axes[2].legend(loc="best", fontsize=8)
    axes[3].set_title("the same, seen along hand_base y")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
