"""``hingelab bench perception``: registration vs Open3D ICP, encoder quality, tool-state speed, the camera.

Held-out clouds (seeds the training data never used), all in ``hand_base``:

* registration: the tool around its in-hand pose (+-30 degrees per Euler angle, +-2 cm:
  the paper's perturbation range), openings uniform over the hinge range, 3 mm noise,
  20% removal. Ours and Open3D's point-to-point ICP start from the same nominal in-hand
  pose and match against the same canonical cloud (1024 points at the reference opening);
  Open3D gets 30 iterations and a 3 cm correspondence distance. Errors are of the tool
  (leg a) frame; time per cloud is wall time (ours batched and one at a time).
* encoder: clouds like its training data (5 mm noise, 20% removal) and like the sim's
  (3 mm), registered by the same pipeline: Chamfer of the reconstruction, R^2 of the calibration (fitted on the
  training set, stored in the checkpoint) and the spread of z at fixed openings (pose,
  noise and occlusion vary) against the extent of z over the opening range.
* speed: tool-state updates per second (cloud synthesis + registration + encoder) with
  1 and 64 clouds per update.
* tracking: a resting tool, sim-like clouds: the tracked pose's rotation change per step
  (all of it noise) and omega_bar, with the motion prior and frame by frame (no prior).
* camera: rendered depth frames per second (render, noise model, cloud pipeline), ToolShape-v0
  env steps per second with camera perception against synthesized clouds (same seeds, random
  actions), and the pipeline's outlier removal and 2 mm voxel grid (numpy + scipy) against
  Open3D's ``remove_statistical_outlier`` and ``voxel_down_sample`` on the same tool points from
  rendered frames: time, and whether the results agree (points kept, voxels, centroid distance).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
from scipy.spatial import cKDTree

from hingelab.bench.table import BenchTable
from hingelab.camera import AZURE_KINECT_NFOV_UNBINNED
from hingelab.envs import TOOL_SHAPE_ID
from hingelab.errors import ConfigError
from hingelab.paths import ANALYSIS_DIR
from hingelab.perception.camera_cloud import (
    ToolCloudConfig,
    crop,
    depth_to_points,
    remove_statistical_outliers,
    transform,
    voxel_downsample,
)
from hingelab.perception.clouds import CloudRealism, CloudSynthesizer, ToolGeometry
from hingelab.perception.encoder import load_encoder
from hingelab.perception.registration import (
    CanonicalRegistration,
    RegistrationConfig,
    TrackingConfig,
    rotation_error_rad,
)
from hingelab.perception.synthetic_dataset import nominal_tool_pose, sample_clouds
from hingelab.perception.tool_perception import CameraClouds
from hingelab.perception.tool_state import ToolState
from hingelab.perception.train_encoder import mean_chamfer_mm2, register_to_tool_frame, surface_targets
from hingelab.sim.core import SimCore

# the code and models this benchmark measures (the bench module itself: hingelab.bench.measured_paths);
# the tool's geometry comes from tweezer.xml, its frame names from sim/names.py
MEASURES = ("platform/hingelab/perception", "platform/hingelab/sim/names.py", "assets/tweezer",
            "assets/checkpoints/encoder.pt", "platform/hingelab/camera.py", "platform/hingelab/sim/rig_camera.py",
            "platform/hingelab/sim/depth_render.py", "platform/hingelab/sim/depth_noise.py",
            "platform/hingelab/perception/tool_perception.py", "platform/hingelab/envs/__init__.py",
            "platform/hingelab/sim/core.py")

PLOT_PATH = ANALYSIS_DIR / "perception" / "latent_space.png"
SEED = 2026  # held-out: datasets and training use small seeds


def _require_open3d():
    try:
        import open3d  # optional (hingelab[bench]) and absent from a plain install: its absence is reported here
    except ImportError as exc:
        if "libusb" in str(exc):  # open3d's wheel links the system's libusb (for its RealSense support)
            raise ConfigError("Open3D is installed but needs the system library libusb-1.0, which is missing; "
                              "on Debian or Ubuntu: apt-get install libusb-1.0-0") from exc
        raise ConfigError("the perception bench compares with Open3D's ICP, which is not installed; "
                          "pip install 'hingelab[bench]' (the open3d-cpu package)") from exc
    return open3d


def _in_hand_clouds(n: int, seed: int, noise_m: float):
    geometry = ToolGeometry.default()
    realism = CloudRealism(noise_m, 0.2, 0.0, 0.0)
    return sample_clouds(np.random.default_rng(seed), n, geometry, realism, np.deg2rad(30.0), 0.02)


def _errors(rot_est, pos_est, rot_true, pos_true):
    return np.rad2deg(rotation_error_rad(rot_est, rot_true)), 1000 * np.linalg.norm(pos_est - pos_true, axis=1)


def _row(method: str, rot_err, pos_err, ms_per_cloud: float) -> dict:
    return {"method": method, "rot median (deg)": float(np.median(rot_err)),
            "rot p95 (deg)": float(np.percentile(rot_err, 95)), "trans median (mm)": float(np.median(pos_err)),
            "trans p95 (mm)": float(np.percentile(pos_err, 95)), "ms per cloud": ms_per_cloud}


def bench_registration(n: int, rows: list, notes: list) -> dict:
    o3d = _require_open3d()
    data = _in_hand_clouds(n, SEED, 0.003)
    clouds, rot_true, pos_true, theta = data["points"], data["rotation"], data["position"], data["hinge_angle"]
    registration = CanonicalRegistration()
    prior = nominal_tool_pose()
    registration.register(clouds[:2], prior=prior)  # warm up
    start = time.perf_counter()
    ours = registration.register(clouds, prior=prior)
    ours_ms = 1000 * (time.perf_counter() - start) / n
    start = time.perf_counter()
    for cloud in clouds[: min(n, 100)]:
        registration.register(cloud, prior=prior)
    ours_single_ms = 1000 * (time.perf_counter() - start) / min(n, 100)
    start = time.perf_counter()
    ours_global = registration.register(clouds)
    global_ms = 1000 * (time.perf_counter() - start) / n

    target = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(registration.canonical))
    init = np.eye(4)
    init[:3, :3], init[:3, 3] = prior
    init_inverse = np.linalg.inv(init)
    method = o3d.pipelines.registration.TransformationEstimationPointToPoint()
    criteria = o3d.pipelines.registration.ICPConvergenceCriteria(max_iteration=30)
    rot_o3d, pos_o3d = np.empty_like(rot_true), np.empty_like(pos_true)
    start = time.perf_counter()
    for k, cloud in enumerate(clouds):
        source = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cloud.astype(np.float64)))
        result = o3d.pipelines.registration.registration_icp(source, target, 0.03, init_inverse, method, criteria)
        pose = np.linalg.inv(result.transformation)  # cloud -> canonical, inverted: the tool pose
        rot_o3d[k], pos_o3d[k] = pose[:3, :3], pose[:3, 3]
    o3d_ms = 1000 * (time.perf_counter() - start) / n

    err_ours = _errors(ours.rotation, ours.translation, rot_true, pos_true)
    err_global = _errors(ours_global.rotation, ours_global.translation, rot_true, pos_true)
    err_o3d = _errors(rot_o3d, pos_o3d, rot_true, pos_true)
    rows.append(_row("ours: SVD ICP, articulated, batched (prior: in-hand pose)", *err_ours, ours_ms))
    rows.append(_row("ours: same, one cloud at a time", *err_ours, ours_single_ms))
    rows.append(_row("ours: no prior (global hypotheses), batched", *err_global, global_ms))
    rows.append(_row("Open3D point-to-point ICP (prior: in-hand pose)", *err_o3d, o3d_ms))
    thirds = np.array_split(np.argsort(theta), 3)
    for name, (rot_err, pos_err) in (("ours", err_ours), ("Open3D", err_o3d)):
        notes.append(f"{name}, rotation median (deg) by opening third (low to high): " + ", ".join(
            f"{np.median(rot_err[i]):.2f}" for i in thirds) + "; translation median (mm): " + ", ".join(
            f"{np.median(pos_err[i]):.2f}" for i in thirds))
    notes.append("ours also estimates the opening: mean |error| "
                 f"{np.rad2deg(np.abs(ours.hinge_angle - theta).mean()):.2f} deg over {n} clouds")
    gross = lambda e: int((e[0] > 45).sum())  # noqa: E731
    notes.append(f"gross failures (rotation error > 45 deg): ours {gross(err_ours)}, ours without prior "
                 f"{gross(err_global)}, Open3D {gross(err_o3d)} of {n}")
    return {"rot_median": (np.median(err_ours[0]), np.median(err_o3d[0])),
            "rot_p95": (np.percentile(err_ours[0], 95), np.percentile(err_o3d[0], 95)),
            "trans_median": (np.median(err_ours[1]), np.median(err_o3d[1])),
            "trans_p95": (np.percentile(err_ours[1], 95), np.percentile(err_o3d[1], 95)),
            "ms_batched": (ours_ms, o3d_ms), "ms_single": (ours_single_ms, o3d_ms)}


def bench_encoder(n: int, per_opening: int, noise_m: float, rows: list, notes: list, plot: Path | None,
                  encoder_path: Path | None = None) -> dict:
    encoder = load_encoder(encoder_path)
    if encoder.calibration is None:
        raise ConfigError(f"the encoder {encoder_path or 'shipped'} has no calibration; retrain it with "
                          "`hingelab train encoder`")
    geometry = ToolGeometry.default()
    registration = CanonicalRegistration(geometry, RegistrationConfig(**encoder.registration_config))
    data = _in_hand_clouds(n, SEED + 1, noise_m)
    clouds, _ = register_to_tool_frame(data["points"], registration)
    targets = surface_targets(geometry, data["hinge_angle"], encoder.model.config.target_points)
    chamfer = mean_chamfer_mm2(encoder.model, clouds, targets)
    z = encoder.encode(clouds)
    gap = geometry.tip_gap_m(data["hinge_angle"])
    held_out = encoder.calibration.evaluate(z, data["hinge_angle"], gap)
    # spread at fixed openings (pose, noise, occlusion vary) vs the extent over the range
    openings = np.linspace(*geometry.hinge_range, 7)
    rng = np.random.default_rng(SEED + 2)
    realism = CloudRealism(noise_m, 0.2, 0.0, 0.0)
    within, means = [], []
    for theta in openings:
        poses = _in_hand_clouds(per_opening, int(rng.integers(1 << 30)), noise_m)
        synth = CloudSynthesizer(geometry, realism, seed=int(rng.integers(1 << 30)))
        points = synth.from_tool_pose(poses["rotation"], poses["position"], np.full(per_opening, theta))
        s = encoder.calibration.coordinate(encoder.encode(register_to_tool_frame(points, registration)[0]))
        within.append(s.std())
        means.append(s.mean())
    extent = float(np.ptp(means))
    spread_ratio = float(np.mean(within) / max(extent, 1e-12))
    rows.append({"method": f"encoder, held-out clouds, {noise_m * 1000:g} mm noise, 20% removal",
                 "chamfer (mm^2)": chamfer, "R^2 opening": held_out["r2_opening"], "R^2 tip gap": held_out["r2_gap"],
                 "opening MAE (deg)": float(np.rad2deg(held_out["mae_opening_rad"])),
                 "opening bias (mrad)": 1000 * held_out["bias_opening_rad"],
                 "gap MAE (mm)": held_out["mae_gap_mm"], "z spread / extent": spread_ratio})
    notes.append(f"{noise_m * 1000:g} mm noise: z along its principal axis at openings "
                 f"{', '.join(f'{t:.2f}' for t in openings)} rad: means {', '.join(f'{m:+.3f}' for m in means)}; "
                 f"std at one opening {np.mean(within):.4f} (mean over openings, {per_opening} clouds each: pose, "
                 f"noise, occlusion vary), extent over the range {extent:.3f}")
    if plot is not None:
        _plot_latents(z, data["hinge_angle"], encoder.calibration, plot)
    return {"chamfer": chamfer, "r2": held_out["r2_opening"], "spread_ratio": spread_ratio,
            "bias_mrad": 1000 * held_out["bias_opening_rad"]}


def _plot_latents(z, opening, calibration, path) -> None:
    # matplotlib only when a plot is asked for; the Agg backend is chosen before pyplot is imported
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path.parent.mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(figsize=(6, 5))
    points = ax.scatter(z[:, 0], z[:, 1], c=np.rad2deg(opening), cmap="viridis", s=6)
    curve = calibration.z_for_opening(np.linspace(*calibration.opening_range, 100))
    ax.plot(curve[:, 0], curve[:, 1], "r-", lw=1.5, label="calibration z(opening)")
    fig.colorbar(points, label="opening (deg)")
    ax.set_xlabel("z[0]")
    ax.set_ylabel("z[1]")
    ax.set_title("Tool latent space, held-out clouds")
    ax.legend(loc="best")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def bench_tool_state(steps: int, rows: list) -> dict:
    """Updates per second for 1 and 64 tools: ``steps`` updates of 64 clouds, 10x as many of one."""
    rot0, pos0 = nominal_tool_pose()
    out = {}
    for n_tools in (1, 64):
        state = ToolState(n_tools=n_tools)
        synth = CloudSynthesizer(ToolGeometry.default(), CloudRealism(), seed=SEED)
        synth.new_episode()
        rot, pos = np.repeat(rot0[None], n_tools, 0), np.repeat(pos0[None], n_tools, 0)
        state.update(synth.from_tool_pose(rot, pos, np.full(n_tools, 0.1)))  # warm up
        n_steps = steps * (10 if n_tools == 1 else 1)  # one cloud is quick: ten times as many to time
        start = time.perf_counter()
        for k in range(n_steps):
            theta = np.full(n_tools, 0.15 + 0.1 * np.sin(0.2 * k))
            state.update(synth.from_tool_pose(rot, pos, theta))
        seconds = time.perf_counter() - start
        out[n_tools] = n_steps * n_tools / seconds
        rows.append({"method": f"tool state, {n_tools} cloud{'s' if n_tools > 1 else ''} per update",
                     "updates/s": out[n_tools], "ms per update": 1000 * seconds / n_steps})
    return out


def bench_tracking(episodes: int, steps: int, rows: list) -> dict:
    """A resting tool through sim-like clouds (3 mm, 20%, a per-episode pose error): how much the
    tracked pose moves per step (any of it is noise) with the motion prior and frame by frame."""
    frame_by_frame = TrackingConfig(rotation_prior_m=0.0, translation_prior=0.0, predict_motion=0.0, max_iterations=8)
    out = {}
    for label, tracking in (("motion prior", TrackingConfig()), ("frame by frame", frame_by_frame)):
        state = ToolState(tracking=tracking)
        rot0, pos0 = state.prior
        turns, omega_bar = [], []
        for episode in range(episodes):
            synth = CloudSynthesizer(ToolGeometry.default(), CloudRealism(), seed=SEED + episode)
            synth.new_episode()
            state.reset()
            previous = None
            for _ in range(steps):
                sample = state.update(synth.from_tool_pose(rot0, pos0, 0.12))
                if previous is not None:
                    turns.append(np.rad2deg(rotation_error_rad(sample.rotation[0], previous)))
                    omega_bar.append(np.abs(sample.angular_velocity_smoothed[0]).mean())
                previous = sample.rotation[0]
        out[label] = float(np.median(turns))
        rows.append({"method": f"tracking at rest, {label}", "step rot median (deg)": out[label],
                     "step rot p95 (deg)": float(np.percentile(turns, 95)), "mean |omega_bar| (rad/s)":
                     float(np.mean(omega_bar))})
    return out


def _camera_points(frames: int) -> list[np.ndarray]:
    """The tool's masked points (hand_base, before outlier removal) of rendered, noisy frames of
    ToolShape-v0 with random finger motion, and the time per frame of the whole camera path."""
    env = gym.make(TOOL_SHAPE_ID, perception="camera")
    points = []
    try:
        env.reset(seed=SEED)
        rng = np.random.default_rng(SEED)
        for _ in range(frames):
            env.step(rng.uniform(-0.3, 0.3, 9))
            camera = env.unwrapped.perception.camera
            f, config = camera.frame, camera.config
            raw = transform(depth_to_points(f.depth, f.intrinsics, f.tool_mask), f.camera_rotation, f.camera_position)
            points.append(crop(raw, config.crop_low, config.crop_high))
    finally:
        env.close()
    return points


def _env_steps_per_second(perception: str, steps: int) -> float:
    env = gym.make(TOOL_SHAPE_ID, perception=perception)
    try:
        env.reset(seed=SEED)
        env.step(np.zeros(9))  # the renderer's context is made on the first frames
        rng = np.random.default_rng(SEED)
        start = time.perf_counter()
        for _ in range(steps):
            env.step(rng.uniform(-0.3, 0.3, 9))
        return steps / (time.perf_counter() - start)
    finally:
        env.close()


def bench_camera(frames: int, rows: list, notes: list) -> dict:
    """Camera frames and env steps per second; the pipeline's filters against Open3D's on the same points."""
    o3d = _require_open3d()
    out = {}
    # frames per second of the camera path alone: render (depth + segmentation), noise, pipeline
    sim = SimCore("tool_shape", camera=AZURE_KINECT_NFOV_UNBINNED)
    sim.reset(seed=SEED)
    camera = CameraClouds()
    camera.new_episode(SEED)
    try:
        camera.cloud(sim)  # the GL context
        start = time.perf_counter()
        for _ in range(frames):
            camera.cloud(sim)
        out["frames_per_s"] = frames / (time.perf_counter() - start)
    finally:
        camera.close()
    rows.append({"method": f"camera frames ({AZURE_KINECT_NFOV_UNBINNED.width}x{AZURE_KINECT_NFOV_UNBINNED.height}: "
                           "render, noise, pipeline)", "updates/s": out["frames_per_s"],
                 "ms per update": 1000 / out["frames_per_s"]})
    for perception in ("synthesized", "camera"):
        out[f"env_{perception}"] = _env_steps_per_second(perception, frames)
        rows.append({"method": f"ToolShape-v0 env steps, {perception} perception",
                     "updates/s": out[f"env_{perception}"], "ms per update": 1000 / out[f"env_{perception}"]})
    # the filters on the same points, ours and Open3D's
    config = ToolCloudConfig()
    clouds = _camera_points(frames)
    ours_s = o3d_s = 0.0
    kept_ours = kept_o3d = voxels_ours = voxels_o3d = 0
    gaps = []
    for pts in clouds:
        start = time.perf_counter()
        kept = remove_statistical_outliers(pts, config.outlier_neighbours, config.outlier_std_ratio)
        vox = voxel_downsample(kept, config.voxel_m)
        ours_s += time.perf_counter() - start
        start = time.perf_counter()
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
        filtered, _ = cloud.remove_statistical_outlier(nb_neighbors=config.outlier_neighbours,
                                                       std_ratio=config.outlier_std_ratio)
        down = np.asarray(filtered.voxel_down_sample(config.voxel_m).points)
        o3d_s += time.perf_counter() - start
        kept_ours, kept_o3d = kept_ours + len(kept), kept_o3d + len(filtered.points)
        voxels_ours, voxels_o3d = voxels_ours + len(vox), voxels_o3d + len(down)
        gaps.append(cKDTree(down).query(vox)[0])
    gaps = np.concatenate(gaps)
    points_in = sum(len(p) for p in clouds)
    out.update(ours_ms=1000 * ours_s / len(clouds), o3d_ms=1000 * o3d_s / len(clouds))
    rows.append({"method": "camera pipeline filters, ours (scipy cKDTree, numpy voxels)",
                 "ms per cloud": out["ours_ms"]})
    rows.append({"method": "camera pipeline filters, Open3D (remove_statistical_outlier, voxel_down_sample)",
                 "ms per cloud": out["o3d_ms"]})
    out["kept_ratio"] = kept_ours / kept_o3d
    out["voxel_ratio"] = voxels_ours / voxels_o3d
    notes.append(f"camera pipeline filters on {len(clouds)} rendered frames' tool points "
                 f"({points_in / len(clouds):.0f} per frame): outlier removal kept {kept_ours} (ours) and {kept_o3d} "
                 f"(Open3D) points, the 2 mm grid made {voxels_ours} and {voxels_o3d} voxels; each of our voxel "
                 f"centroids lies {1000 * np.median(gaps):.3f} mm (median) and {1000 * gaps.max():.3f} mm (max) from "
                 "Open3D's nearest")
    return out


def run(quick: bool = False, encoder: Path | None = None) -> BenchTable:
    """``encoder``: a checkpoint to measure instead of the shipped one (the encoder rows)."""
    n = 64 if quick else 400
    rows: list[dict] = []
    notes: list[str] = []
    # speed first: torch's batched encoder and Open3D leave thread pools spinning for a while after them
    speed = bench_tool_state(5 if quick else 40, rows)
    reg = bench_registration(n, rows, notes)
    # a quick run (tests) must not overwrite the committed plot
    plot = Path(tempfile.gettempdir()) / "hingelab_latent_space_quick.png" if quick else PLOT_PATH
    if encoder is not None and not quick:  # the committed plot shows the shipped encoder
        plot = ANALYSIS_DIR / "perception" / f"latent_space_{Path(encoder).stem}.png"
    enc = bench_encoder(200 if quick else 1000, 8 if quick else 32, 0.005, rows, notes, plot=plot,
                        encoder_path=encoder)
    runtime = bench_encoder(200 if quick else 1000, 8 if quick else 32, 0.003, rows, notes, plot=None,
                            encoder_path=encoder)
    tracking = bench_tracking(2 if quick else 10, 20 if quick else 60, rows)
    camera = bench_camera(10 if quick else 100, rows, notes)
    notes.append(f"latent-space plot: {plot if quick else plot.relative_to(ANALYSIS_DIR.parent)}")
    notes.append("ratios are ours / Open3D (below 1: ours better or faster); the clouds are held out "
                 f"(seed {SEED}), {n} for registration")
    columns = ["method", "rot median (deg)", "rot p95 (deg)", "trans median (mm)", "trans p95 (mm)", "ms per cloud",
               "chamfer (mm^2)", "R^2 opening", "R^2 tip gap", "opening MAE (deg)", "opening bias (mrad)",
               "gap MAE (mm)",
               "z spread / extent", "updates/s", "ms per update", "step rot median (deg)", "step rot p95 (deg)",
               "mean |omega_bar| (rad/s)"]
    ratios = {f"{k} ours/open3d": float(a / b) for k, (a, b) in reg.items()}
    ratios.update({"encoder calibration R^2, 5 mm noise (goal >= 0.95)": float(enc["r2"]),
                   "encoder calibration R^2, 3 mm noise (the sim's)": float(runtime["r2"]),
                   "z spread at one opening / extent over the range, 5 mm (goal < 0.10)": enc["spread_ratio"],
                   "z spread at one opening / extent over the range, 3 mm": runtime["spread_ratio"],
                   "opening bias (read - true), 3 mm clouds (the sim's), mrad": runtime["bias_mrad"],
                   "tool-state updates/s, 64 vs 1 cloud per update": speed[64] / speed[1],
                   "rotation change per step at rest, motion prior / frame by frame":
                       tracking["motion prior"] / tracking["frame by frame"],
                   "camera frames/s (render, noise, pipeline)": camera["frames_per_s"],
                   "ToolShape-v0 env steps/s, camera / synthesized perception":
                       camera["env_camera"] / camera["env_synthesized"],
                   "camera pipeline filters ms, ours/open3d": camera["ours_ms"] / camera["o3d_ms"],
                   "camera pipeline outlier removal, points kept ours/open3d": camera["kept_ratio"],
                   "camera pipeline voxels, ours/open3d": camera["voxel_ratio"]})
    return BenchTable(name="perception",
                      title="Tool perception: registration vs Open3D ICP, encoder, tool state, depth camera",
                      columns=columns, rows=rows, ratios=ratios, notes=notes,
                      config={"quick": quick, "registration_clouds": n, "seed": SEED,
                              "encoder": str(encoder) if encoder else "shipped"})
