"""``hingelab datasets info|index|verify|recover|export|import-ros2``: look after episode datasets."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from hingelab.cli.names import EXPORT_FORMATS, OBJECT_ESTIMATORS, OBJECT_FROM_CLOUD_DEFAULT
from hingelab.cli.options import add_on_corrupt
from hingelab.errors import ConfigError
from hingelab.folder_lock import folder_lock
from hingelab.out_dir import DATASET, MINARI_ROOT, NEW, check_out, check_out_file
from hingelab.paths import DATASETS_DIR


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "datasets",
        help="inspect, index, verify, recover, export and import (ROS 2 bags) episode datasets",
        description="Look after episode datasets (folders of MCAP episode files, see datasets/README.md). "
                    f"Dataset folders are usually under {DATASETS_DIR}.",
    )
    verbs = p.add_subparsers(title="subcommands", metavar="SUBCOMMAND", required=True)

    info = verbs.add_parser("info", help="the dataset card and episode counts per source and object")
    info.add_argument("dir", type=Path, help="dataset folder (holds dataset.json and episodes/)")
    add_on_corrupt(info)
    info.set_defaults(func=run_info)

    index = verbs.add_parser("index", help="rebuild index.parquet from the episode files alone")
    index.add_argument("dir", type=Path, help="dataset folder")
    add_on_corrupt(index)
    index.set_defaults(func=run_index)

    verify = verbs.add_parser("verify", help="check every episode file; exit 1 naming each bad one")
    verify.add_argument("dir", type=Path, help="dataset folder")
    verify.set_defaults(func=run_verify)

    recover = verbs.add_parser(
        "recover", help="salvage the complete messages of a cut-off episode file, or of every .partial of a dataset",
        description="FILE --out NEW: salvage one cut-off or corrupt episode file into NEW. DIR (a dataset folder): "
                    "salvage every leftover .partial file of DIR/episodes into its final name (marked "
                    "recovered=true) and remove the .partial; with --discard, remove them instead.")
    recover.add_argument("file", type=Path,
                         help="the cut-off file (usually episodes/<id>.mcap.partial), or a dataset folder")
    recover.add_argument("--out", type=Path, default=None, help="the new episode file to write (one file only)")
    recover.add_argument("--discard", action="store_true", help="a dataset folder: remove its .partial files")
    recover.set_defaults(func=run_recover)

    export = verbs.add_parser(
        "export", help="export a dataset as a Minari dataset, a LeRobotDataset (v3.0) or ROS 2 bags",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(
            "Write a dataset in a layout its neighbours' own libraries load (details: datasets/README.md, Exports).\n\n"
            "--format minari: --out is a Minari datasets root (what MINARI_DATASETS_PATH names; it may hold other\n"
            "  datasets, e.g. ~/.minari/datasets). The export writes OUT/NAMESPACE/NAME-vN/data/{main_data.hdf5,\n"
            "  metadata.json} with the id --dataset-id (default hingelab/<folder name>-v0), the env's observation and\n"
            "  action spaces and requirements [\"hingelab>=VERSION\"], and prints how to open it:\n"
            "  MINARI_DATASETS_PATH=OUT, minari.load_dataset(ID). Episodes without a final observation\n"
            "  (recovered files) are skipped and counted: Minari needs T+1 observations.\n"
            "--format lerobot: --out is the new LeRobotDataset v3.0 folder (meta/info.json, stats.json,\n"
            "  hingelab.json, tasks.parquet, meta/episodes/, data/chunk-000/file-000.parquet):\n"
            "  LeRobotDataset(REPO_ID, root=OUT). Trials export with their depth frames (observation.images.depth).\n"
            "--format ros2: --out is a new folder of rosbag2 folders (MCAP storage), one per episode: "
            "OUT/<episode_id>/\n"
            "  with every topic the episode has (joint states, tool cloud, /tf and /tf_static, depth images and\n"
            "  camera_info, labelled actions, poses, /hingelab/episode metadata; docs/ros2.md); `ros2 bag info`,\n"
            "  rosbags and `hingelab datasets import-ros2 OUT/<episode_id>` (no --topic needed) read them.\n\n"
            "Tool clouds are aligned to the observations by log time (Minari: infos/tool_points; LeRobot:\n"
            "observation.points). A failed export leaves nothing behind: it writes a hidden temporary folder\n"
            "and renames it into place at the end."),
    )
    export.add_argument("dir", type=Path, help="dataset folder")
    export.add_argument("--format", required=True, metavar="FORMAT",
                        help=f"target layout: {', '.join(EXPORT_FORMATS)} (or a plug-in's format)")
    export.add_argument("--out", type=Path, required=True,
                        help="minari: the datasets root (MINARI_DATASETS_PATH); lerobot: the new dataset folder; "
                             "ros2: the new folder of bags")
    export.add_argument("--dataset-id", default=None, metavar="NAMESPACE/NAME-vN",
                        help="minari only: the dataset id (default hingelab/<dataset folder name>-v0); "
                             "must not exist under --out")
    add_on_corrupt(export)
    export.set_defaults(func=run_export)

    from hingelab.ros2.topics import KINDS  # the topics' table: only for this subcommand's description

    kinds = "\n".join(f"  {k.kind}={k.default}  ({k.msgtype}{'' if k.required else ', optional'}): {k.meaning}"
                      for k in KINDS.values())
    ros2 = verbs.add_parser(
        "import-ros2", help="import ROS 2 bags recorded on the real rig as episodes (source real)",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(
            "Import rosbag2 folders (MCAP or sqlite3 storage) and standalone .mcap bags, without a ROS install, into\n"
            "the dataset folder --out (created; reopened if it holds an earlier import with the same topics). Each\n"
            "start..end of the trial events is one episode (source real): steps at 20 Hz from its start, every\n"
            "stream sampled at its latest message stamped at or before the step (the ages are recorded), the camera\n"
            "cloud put into hand_base by TF and through the camera cloud pipeline to the 256-point tool cloud, the\n"
            "tool pose and latents from the same perception as in simulation. The camera is a PointCloud2 (points)\n"
            "or a 32FC1 depth image with its camera_info (depth, camera_info). The object comes from the object\n"
            "pose topic; a bag without one imports without an object (which train high needs) unless\n"
            "--object-from-cloud estimates it from the camera frames. Topics (KIND=default):\n" + kinds
            + "\nA bag cut off mid-chunk imports what is whole; the summary says what was dropped and why."),
    )
    ros2.add_argument("bags", type=Path, nargs="+", metavar="BAG", help="rosbag2 folder or .mcap file")
    ros2.add_argument("--out", type=Path, required=True, help="the dataset folder to write (source real)")
    ros2.add_argument("--topic", action="append", default=[], metavar="KIND=NAME",
                      help="read KIND from the topic NAME instead of its default (repeatable), e.g. "
                           "--topic points=/k4a/points2")
    ros2.add_argument("--object-from-cloud", nargs="?", const=OBJECT_FROM_CLOUD_DEFAULT, default=None,
                      metavar="ESTIMATOR",
                      help="estimate the object's position and extent from the bag's camera frames (depth image or "
                           "scene PointCloud2) instead of an object pose topic, for a rig without motion capture: "
                           "the object's points by the rig's mask (object_mask topic, with depth images) or else "
                           "the points above the platform inside its footprint minus the tool's, then ESTIMATOR: "
                           f"{', '.join(OBJECT_ESTIMATORS)} (default {OBJECT_FROM_CLOUD_DEFAULT}; "
                           "hingelab.perception.object_estimate). Recorded on /object/estimate with the episode "
                           "key object_perception; a step without an estimate is flagged and keeps the last one; "
                           "a bag's object pose, if any, becomes the estimate's reference (true_position). Give "
                           "it after the bags: right before one it takes the bag's path for ESTIMATOR")
    ros2.add_argument("--no-progress", action="store_true", help="no progress bar")
    ros2.set_defaults(func=run_import_ros2)


def _open(root: Path):
    from hingelab.episodes.dataset import open_dataset  # on run: the parser stays light (hingelab.cli)

    return open_dataset(root)


def run_info(args: argparse.Namespace) -> int:
    dataset = _open(args.dir)
    card, frame, summary = dataset.card, dataset.index, dataset.summary()
    print(f"dataset {card.name!r} at {dataset.root}")
    print(f"  source {card.source}, seed {card.seed}, config {card.config_hash}, schema v{card.schema_version}, "
          f"hingelab {card.hingelab_version} ({card.git_commit}), created {card.created}")
    if len(frame):
        table = frame.groupby(["source", "object"], dropna=False).agg(
            episodes=("file", "size"), steps=("length", "sum"), success_rate=("success", "mean"),
            mean_return=("return", "mean"))
        print(table.to_string())
    print(f"{summary['episodes']} episodes, {summary['steps']} steps, success rate "
          f"{summary['success_rate']:.3f}, {summary['bytes'] / 1e6:.1f} MB, "
          f"{summary['partial_files']} unfinished (.partial) files"
          + ("; run hingelab datasets verify" if summary["partial_files"] else "") + ".")
    return 0


def run_index(args: argparse.Namespace) -> int:
    dataset = _open(args.dir)
    frame = dataset.build_index(rebuild=True, progress=True)
    print(f"Rebuilt {dataset.root / 'index.parquet'} from {len(frame)} episode files "
          f"({int(frame['length'].fillna(0).sum())} steps); "
          f"{len(dataset.partial_files())} unfinished .partial files were left out.")
    return 0


def run_verify(args: argparse.Namespace) -> int:
    from hingelab.episodes.errors import DatasetError  # on run: the parser stays light (hingelab.cli)
    from hingelab.episodes.verify import verify_dataset

    _open(args.dir)
    good, problems = verify_dataset(args.dir, progress=True)
    for problem in problems:
        print(str(problem), file=sys.stderr)
    if problems:
        names = ", ".join(p.path.name for p in problems)
        raise DatasetError(f"{args.dir}: {len(problems)} bad file(s) of {len(good) + len(problems)} ({names}); "
                           "see the lines above for each fix")
    print(f"{args.dir}: all {len(good)} episode files are complete, decode and match their metadata.")
    return 0


def run_recover(args: argparse.Namespace) -> int:
    from hingelab.episodes.recover import (  # on run: the parser stays light (hingelab.cli)
        recover_episode,
        recover_folder,
    )

    if args.out is not None:
        check_out_file(args.out)
    if args.file.is_dir():
        if args.out is not None:
            raise ConfigError("--out names one recovered file; a dataset folder's .partial files are recovered "
                              "under their own names (leave --out out)")
        with folder_lock(args.file, args.argv):  # its .partial files may be a running command's episodes
            result = recover_folder(args.file, discard=args.discard)
        failed = "".join(f"; kept {path.name}: {reason}" for path, reason in result["failed"])
        print(f"{args.file}: recovered {len(result['recovered'])} and removed {len(result['discarded'])} .partial "
              f"files{failed}.")
        return 1 if result["failed"] else 0
    if args.out is None or args.discard:
        raise ConfigError("recover FILE needs --out NEWFILE (and --discard is for a dataset folder)")
    result = recover_episode(args.file, args.out)
    state = (f"cut off at byte {result['cut_at']}" if result["cut_off"] else "complete (nothing was lost)")
    print(f"Recovered {result['messages']} messages ({result['steps']} steps) from {args.file}, which was "
          f"{state}, into {result['out']} (marked recovered=true).")
    return 0


def run_export(args: argparse.Namespace) -> int:
    from hingelab.episodes.export import EXPORTERS, export_dataset  # on run: the parser stays light (hingelab.cli)
    from hingelab.ros2 import bag_export  # noqa: F401  (registers the ros2 export format)

    check_out(args.out, MINARI_ROOT if args.format == "minari" else NEW)  # minari: a datasets root
    if args.format not in EXPORTERS:
        raise ConfigError(f"--format {args.format}: not an export format; choose one of {', '.join(EXPORTERS)}")
    dataset = _open(args.dir)
    result = export_dataset(dataset, args.format, args.out, dataset_id=args.dataset_id, progress=True)
    skipped = "".join(f"; skipped {len(files)} ({reason}): {', '.join(files[:3])}{' ...' if len(files) > 3 else ''}"
                      for reason, files in result.skipped.items())
    notes = "".join(f"; {note}" for note in result.notes)
    print(f"Exported {result.episodes} episodes ({result.frames} steps) of {dataset.root} as {args.format} into "
          f"{result.path}{skipped}{notes}. Load it with {result.load}.")
    return 0


def run_import_ros2(args: argparse.Namespace) -> int:
    from hingelab.ros2.bag_import import import_bags  # on run: the parser stays light (hingelab.cli)
    from hingelab.ros2.object_from_cloud import check_estimator
    from hingelab.ros2.topics import topic_names

    check_out(args.out, DATASET)
    topic_names(args.topic)  # a malformed --topic is refused before anything is read
    if args.object_from_cloud is not None:
        check_estimator(args.object_from_cloud)
    with folder_lock(args.out, args.argv):
        summaries = import_bags(args.bags, args.out, topics=args.topic, progress=not args.no_progress,
                                object_from_cloud=args.object_from_cloud)
    for summary in summaries:
        print(summary.line())
    episodes = sum(len(s.episodes) for s in summaries)
    steps = sum(s.steps for s in summaries)
    dropped = sum(sum(s.dropped.values()) for s in summaries)
    print(f"Imported {episodes} episodes ({steps} steps at 20 Hz) from {len(summaries)} bag(s) into {args.out} "
          f"(source real); {dropped} messages dropped (reasons above). Look at them with hingelab view {args.out}, "
          f"report with hingelab report {args.out} --out analysis/NAME.")
    return 0
