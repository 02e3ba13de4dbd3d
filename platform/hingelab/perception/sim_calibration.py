"""The calibration curve refitted on the latents the envs perceive (``hingelab train encoder --recalibrate-curve``).

``train_encoder`` fits the curve z(opening) on its training clouds: registered from scratch,
at the training data's noise (2-6 mm for the shipped encoder). The envs see 3 mm clouds,
tracked from step to step by ``ToolState``. A PointNet's max pool reads a cloud's extremes, so
the latent of a given opening depends on the noise and on the registration, and the training
curve is off the envs' latents where the tweezer is nearly shut: a shut tweezer in
ToolShape-v0 sits off the shipped curve's closed end by most of a success threshold, and the
reader takes it for slightly open; goals drawn as ``z_for_opening(small opening)`` ask for a
latent that only a slightly open tweezer shows. (The shipped encoder keeps its curve: its policy
learned on those goals; assets/checkpoints/README.md has the measurements.)

Here the curve (and the reader) are fitted on what ``ToolPerception`` produces: per sweep, one
episode's cloud realism (``CloudRealism()``: 3 mm noise, 20% removal, a pose error drawn per
episode) around the nominal in-hand pose, the hinge swept across the range at the pace a
policy moves it, every cloud through ``ToolState`` (tracking, as in the envs). Raw latents are
fitted (the envs' EMA is a linear filter of them: the same curve).

The weights stay, so every latent means the shape it meant; the curve changes what a goal
opening asks for, and with it ``ToolEncoder.fingerprint``. The checkpoint lists the
fingerprints it replaces (``curve["replaces"]``): a low-level policy trained beside one of
them still loads (its inputs are the same latents).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from hingelab.errors import ConfigError
from hingelab.perception.calibration import OpeningCalibration, latent_distance_for_gap
from hingelab.perception.clouds import CloudRealism, CloudSynthesizer, ToolGeometry
from hingelab.perception.encoder import ToolEncoder, load_encoder, rewrite_calibration
from hingelab.perception.synthetic_dataset import nominal_tool_pose
from hingelab.perception.tool_state import ToolState
from hingelab.provenance import code_version
from hingelab.tasks import TOOL_SHAPE_SUCCESS_GAP_MM as SUCCESS_GAP_MM

SWEEP_STEPS = 60  # control steps from one end of the range to the other (~0.005 rad a step: tracking holds)
DWELL_STEPS = 5  # steps held at each end before and after the sweep (where a training-cloud curve is off)
LOWEST_OPENING = -0.0012  # rad: the fingers squeeze the hinge this far past shut (FingerSynergy.theta_range)


def tracked_sweep_latents(encoder: ToolEncoder, sweeps: int = 40, seed: int = 0, realism: CloudRealism = CloudRealism(),
                          progress: bool = True) -> dict[str, np.ndarray]:
    """Latents of ``sweeps`` hinge sweeps as the envs perceive them: {z (M, 2), opening_rad (M,), tip_gap_m (M,)}.

    Sweep k draws its pose error from ``seed + k`` and runs closed -> open (k even) or open ->
    closed (k odd), so both directions of tracking are in the data."""
    if sweeps < 2:
        raise ConfigError(f"a curve needs at least 2 sweeps (one each way), got {sweeps}")
    geometry = ToolGeometry.default()
    rot, pos = nominal_tool_pose()
    synthesizer = CloudSynthesizer(geometry, realism)
    sweep = np.linspace(LOWEST_OPENING, geometry.hinge_range[1], SWEEP_STEPS)
    sweep = np.concatenate([np.full(DWELL_STEPS, sweep[0]), sweep, np.full(DWELL_STEPS, sweep[-1])])
    z, openings = [], []
    for k in tqdm(range(sweeps), desc="curve sweeps", unit="sweep", disable=not progress):
        synthesizer.new_episode(seed + k)
        state = ToolState(encoder=encoder, n_tools=1)
        for opening in (sweep if k % 2 == 0 else sweep[::-1]):
            sample = state.update(synthesizer.from_tool_pose(rot, pos, opening)[None],
                                  n_distinct=synthesizer.n_distinct)
            z.append(sample.z[0].copy())
            openings.append(opening)
    openings = np.asarray(openings)
    return {"z": np.asarray(z), "opening_rad": openings, "tip_gap_m": geometry.tip_gap_m(openings)}


def curve_offsets(calibration: OpeningCalibration, data: dict, edges=(LOWEST_OPENING, 0.01, 0.03, 0.1, 0.2, 0.31)
                  ) -> list[dict]:
    """Per opening band: the distance between the mean latent of ``data`` and the curve there."""
    rows = []
    for low, high in zip(edges[:-1], edges[1:]):
        band = (data["opening_rad"] >= low) & (data["opening_rad"] < high)
        if band.any():
            offset = (data["z"][band] - calibration.z_for_opening(data["opening_rad"][band])).mean(axis=0)
            rows.append({"band_rad": f"{low:.3f}-{high:.3f}", "latents": int(band.sum()),
                         "offset": float(np.linalg.norm(offset))})
    return rows


def recalibrate_curve(checkpoint, sweeps: int = 40, seed: int = 0, progress: bool = True) -> tuple[ToolEncoder, dict]:
    """Refit the calibration curve and reader of ``checkpoint`` on tracked sweeps and rewrite it.

    Fitted on sweeps ``seed .. seed + sweeps - 1``, checked on as many others (``seed + sweeps ..``).
    Returns (the rewritten encoder, metrics: the held-out offsets of the old and the new curve per
    opening band, R^2 of the reader on the held-out sweeps, the fingerprints, the wall time)."""

    started = time.perf_counter()
    checkpoint = Path(checkpoint)
    encoder = load_encoder(checkpoint)
    if encoder.calibration is None:
        raise ConfigError(f"{checkpoint} has no calibration to refit; retrain it with `hingelab train encoder`")
    fit_data = tracked_sweep_latents(encoder, sweeps, seed, progress=progress)
    check_data = tracked_sweep_latents(encoder, sweeps, seed + sweeps, progress=progress)
    old = encoder.calibration
    new = OpeningCalibration.fit(fit_data["z"], fit_data["opening_rad"], fit_data["tip_gap_m"])
    held_out = new.evaluate(check_data["z"], check_data["opening_rad"], check_data["tip_gap_m"])
    metrics = {
        "offsets_before": curve_offsets(old, check_data), "offsets_after": curve_offsets(new, check_data),
        "r2_opening_before": old.evaluate(check_data["z"], check_data["opening_rad"],
                                          check_data["tip_gap_m"])["r2_opening"],
        "r2_opening_after": held_out["r2_opening"], "mae_opening_rad_after": held_out["mae_opening_rad"],
        "success_threshold_before": latent_distance_for_gap(old, SUCCESS_GAP_MM),
        "success_threshold_after": latent_distance_for_gap(new, SUCCESS_GAP_MM),
        "latents": len(fit_data["z"]), "wall_time_s": time.perf_counter() - started,
    }
    replaced = list((encoder.info.get("curve") or {}).get("replaces", [])) + [encoder.fingerprint]
    curve = {"fitted_on": f"{sweeps} tracked sweeps of 3 mm clouds, seeds {seed}-{seed + sweeps - 1}",
             "sweeps": sweeps, "seed": seed, "code_version": code_version(), "replaces": replaced, "metrics": metrics}
    rewritten = rewrite_calibration(checkpoint, encoder, new.to_dict(), curve=curve)
    metrics.update(fingerprint_before=encoder.fingerprint, fingerprint_after=rewritten.fingerprint)
    return rewritten, metrics


__all__ = ["curve_offsets", "recalibrate_curve", "tracked_sweep_latents"]
