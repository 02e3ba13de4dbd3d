"""Train the tool encoder from a ``synthetic_clouds`` dataset (``hingelab train encoder``).

The pipeline is the run-time one: every cloud of the dataset is registered to the
canonical cloud (starting from the nominal in-hand pose) and moved into the tool frame;
the encoder reconstructs the clean surface of the tool at the cloud's ground-truth
opening (a fixed random draw of the sampled surface per cloud). The last
``val_fraction`` of the episodes are held out: per-epoch validation Chamfer and the
calibration R^2 on them are logged. At the end the calibration z <-> opening is fitted
on the training clouds and stored in the checkpoint with the config, data, seed, code
version and every epoch's metrics.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from hingelab.episodes import load_card
from hingelab.errors import ConfigError
from hingelab.perception.calibration import OpeningCalibration
from hingelab.perception.clouds import ToolGeometry, _even_subset
from hingelab.perception.encoder import (
    EncoderConfig,
    PointNetVAE,
    ToolEncoder,
    chamfer,
    load_encoder,
    rewrite_calibration,
    save_checkpoint,
    vae_loss,
)
from hingelab.perception.encoder_config import TrainEncoderConfig
from hingelab.perception.registration import CanonicalRegistration, RegistrationConfig
from hingelab.perception.synthetic_dataset import load_cloud_dataset, nominal_tool_pose
from hingelab.provenance import code_version


def register_to_tool_frame(points_hand: np.ndarray, registration: CanonicalRegistration,
                           batch: int = 250, progress: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Register clouds (M, N, 3) hand_base from the nominal in-hand pose: (clouds in the tool
    frame (M, N, 3) float32, registered rotations (M, 3, 3))."""
    prior = nominal_tool_pose()
    out = np.empty(points_hand.shape, np.float32)
    rotations = np.empty((len(points_hand), 3, 3))
    for start in tqdm(range(0, len(points_hand), batch), desc="register", unit="batch", disable=not progress):
        chunk = points_hand[start:start + batch]
        result = registration.register(chunk, prior=prior)
        out[start:start + batch] = result.to_tool_frame(chunk.astype(np.float64))
        rotations[start:start + batch] = result.rotation
    return out, rotations


def surface_targets(geometry: ToolGeometry, hinge_angle: np.ndarray, n_points: int) -> np.ndarray:
    """Clean tool surfaces at the given openings: (M, n_points, 3) float32, tool frame.

    The same evenly spread subset of the sampled surface for every cloud, so the target is
    a function of the opening alone: nothing else in the input is worth encoding.
    """
    index = _even_subset(geometry.bank_part, n_points)
    local = geometry.bank_points[index]
    is_b = geometry.bank_part[index] == 1
    rot_b, pos_b = geometry.leg_b_pose(hinge_angle)
    moved = local @ np.swapaxes(rot_b, 1, 2) + pos_b[:, None]
    return np.where(is_b[None, :, None], moved, local[None]).astype(np.float32)


def _augment(points: torch.Tensor, train: TrainEncoderConfig, gen: torch.Generator) -> torch.Tensor:
    """Turn and shift each cloud a little (about the tool origin): the residual pose errors of
    registration, which the encoder should not care about (the target stays put)."""
    n = len(points)
    angles = (torch.rand(n, 3, generator=gen) * 2 - 1) * np.deg2rad(train.augment_angle_deg)
    rot = _euler_matrices(angles)
    offset = (torch.rand(n, 1, 3, generator=gen) * 2 - 1) * train.augment_offset_m
    return points @ rot.transpose(1, 2) + offset


def _euler_matrices(angles: torch.Tensor) -> torch.Tensor:
    """(n, 3) extrinsic x-y-z angles -> (n, 3, 3) rotation matrices."""
    c, s = angles.cos(), angles.sin()
    one, zero = torch.ones_like(c[:, 0]), torch.zeros_like(c[:, 0])
    rx = torch.stack([one, zero, zero, zero, c[:, 0], -s[:, 0], zero, s[:, 0], c[:, 0]], 1).view(-1, 3, 3)
    ry = torch.stack([c[:, 1], zero, s[:, 1], zero, one, zero, -s[:, 1], zero, c[:, 1]], 1).view(-1, 3, 3)
    rz = torch.stack([c[:, 2], -s[:, 2], zero, s[:, 2], c[:, 2], zero, zero, zero, one], 1).view(-1, 3, 3)
    return rz @ ry @ rx


@torch.no_grad()
def encode_all(model: PointNetVAE, clouds: np.ndarray, batch: int = 512) -> np.ndarray:
    """Latent means (M, latent) of clouds in the tool frame."""
    model.eval()
    return np.concatenate([model.encode(torch.from_numpy(clouds[i:i + batch]))[0].numpy()
                           for i in range(0, len(clouds), batch)])


@torch.no_grad()
def mean_chamfer_mm2(model: PointNetVAE, clouds: np.ndarray, targets: np.ndarray, batch: int = 512) -> float:
    """Mean Chamfer distance (decoded latent mean vs the clean surface), mm^2."""
    model.eval()
    total = 0.0
    for i in range(0, len(clouds), batch):
        recon = model(torch.from_numpy(clouds[i:i + batch]), sample=False)[0]
        total += float(chamfer(recon, torch.from_numpy(targets[i:i + batch])).sum())
    return 1e6 * total / len(clouds)


def _split(data: dict, val_fraction: float) -> tuple[np.ndarray, np.ndarray]:
    """(training, held-out) cloud indices: the last ``val_fraction`` of the episodes are held out."""
    episodes = np.unique(data["episode"])
    n_val = max(1, int(round(val_fraction * len(episodes)))) if len(episodes) > 1 else 0
    is_val = np.isin(data["episode"], episodes[len(episodes) - n_val:])
    tr, va = np.flatnonzero(~is_val), np.flatnonzero(is_val)
    return tr, (tr if n_val == 0 else va)  # one episode: validate on the training clouds


def recalibrate_encoder(data_dir, checkpoint, progress: bool = True) -> tuple[ToolEncoder, dict]:
    """Fit the latent -> opening reader (``OpeningCalibration.with_reader``) of a trained checkpoint
    on the training split of the dataset it was trained on, and rewrite the checkpoint.

    The weights and the calibration curve are kept, so ``ToolEncoder.fingerprint`` and every
    latent goal stay the same; the reader's held-out R^2 and where it was fitted go into the
    checkpoint's ``reader`` record. Returns (encoder, metrics)."""
    started = time.perf_counter()
    checkpoint = Path(checkpoint)
    encoder = load_encoder(checkpoint)
    if encoder.calibration is None:
        raise ConfigError(f"{checkpoint} has no calibration to add a reader to; "
                          "retrain it with `hingelab train encoder`")
    data = load_cloud_dataset(data_dir, progress=progress)
    trained_on = (encoder.info.get("data") or {}).get("config_hash")
    card = load_card(data_dir)
    if trained_on is not None and card.config_hash != trained_on:
        raise ConfigError(f"{data_dir} (config {card.config_hash}) is not the dataset {checkpoint} was trained on "
                          f"(config {trained_on}); regenerate it with the command in the checkpoint's README")
    registration = CanonicalRegistration(ToolGeometry.default(), RegistrationConfig(**encoder.registration_config))
    clouds, _ = register_to_tool_frame(data["points"], registration, progress=progress)
    train = TrainEncoderConfig(**{k: v for k, v in (encoder.info.get("train_config") or {}).items()
                                  if k in TrainEncoderConfig.__dataclass_fields__})
    tr, va = _split(data, train.val_fraction)
    calibration = encoder.calibration.with_reader(encode_all(encoder.model, clouds[tr]), data["hinge_angle"][tr])
    held_out = calibration.evaluate(encode_all(encoder.model, clouds[va]), data["hinge_angle"][va],
                                    data["tip_gap_m"][va])
    metrics = {"reader_r2_opening_train": calibration.reader_r2_opening,
               **{f"{k}_val": v for k, v in held_out.items()}, "wall_time_s": time.perf_counter() - started}
    reader = {"data": str(Path(data_dir).resolve()), "config_hash": card.config_hash,
              "code_version": code_version(), "metrics": metrics}
    return rewrite_calibration(checkpoint, encoder, calibration.to_dict(), reader=reader), metrics


def train_encoder(data_dir, out_path, train: TrainEncoderConfig = TrainEncoderConfig(),
                  encoder: EncoderConfig = EncoderConfig(),
                  registration_config: RegistrationConfig = RegistrationConfig(),
                  progress: bool = True, log=print) -> tuple[ToolEncoder, dict]:
    """Train, fit the calibration, write the checkpoint; returns (encoder, summary metrics)."""
    if train.epochs < 1 or train.batch_size < 2:
        raise ConfigError(f"epochs must be >= 1 and batch size >= 2, got {train.epochs}, {train.batch_size}")
    started = time.perf_counter()
    torch.manual_seed(train.seed)
    torch.set_num_threads(train.threads)
    geometry = ToolGeometry.default()
    data = load_cloud_dataset(data_dir, progress=progress)
    registration = CanonicalRegistration(geometry, registration_config)
    clouds, _ = register_to_tool_frame(data["points"], registration, train.register_batch, progress)
    targets = surface_targets(geometry, data["hinge_angle"], encoder.target_points)
    tr, va = _split(data, train.val_fraction)
    model = PointNetVAE(encoder)
    optimizer = torch.optim.Adam(model.parameters(), lr=train.learning_rate)
    scheduler = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, T_max=train.epochs)
    gen = torch.Generator().manual_seed(train.seed)
    x_tr, y_tr = torch.from_numpy(clouds[tr]), torch.from_numpy(targets[tr])
    history = []
    step = 0
    warmup_steps = max(1.0, train.kl_warmup_fraction * train.epochs * -(-len(tr) // train.batch_size))
    bar = tqdm(range(train.epochs), desc="train encoder", unit="epoch", disable=not progress)
    for epoch in bar:
        model.train()
        order = torch.randperm(len(tr), generator=gen)
        sums = np.zeros(3)
        for start in range(0, len(tr), train.batch_size):
            idx = order[start:start + train.batch_size]
            step += 1
            x = _augment(x_tr[idx], train, gen)
            loss, rec, kl = vae_loss(model, x, y_tr[idx], beta_scale=min(1.0, step / warmup_steps))
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            sums += np.array([loss.item(), rec.item(), kl.item()]) * len(idx)
        scheduler.step()
        z_val = encode_all(model, clouds[va])
        fit = tr[:: max(1, len(tr) // 2000)]  # a subset is plenty for the per-epoch figure
        calib = OpeningCalibration.fit(encode_all(model, clouds[fit]), data["hinge_angle"][fit], data["tip_gap_m"][fit])
        row = {"epoch": epoch + 1, "loss": sums[0] / len(tr), "chamfer": sums[1] / len(tr), "kl": sums[2] / len(tr),
               "val_chamfer_mm2": mean_chamfer_mm2(model, clouds[va], targets[va]),
               "val_r2_opening": calib.evaluate(z_val, data["hinge_angle"][va], data["tip_gap_m"][va])["r2_opening"]}
        history.append(row)
        bar.set_postfix(loss=f"{row['loss']:.4f}", val_cd=f"{row['val_chamfer_mm2']:.2f}mm2",
                        r2=f"{row['val_r2_opening']:.3f}")
        if not progress:
            log(json.dumps({k: round(v, 6) if isinstance(v, float) else v for k, v in row.items()}))
    z_tr = encode_all(model, clouds[tr])
    calibration = OpeningCalibration.fit(z_tr, data["hinge_angle"][tr], data["tip_gap_m"][tr])
    held_out = calibration.evaluate(encode_all(model, clouds[va]), data["hinge_angle"][va], data["tip_gap_m"][va])
    metrics = {"train_clouds": int(len(tr)), "val_clouds": int(len(va)),
               "val_chamfer_mm2": history[-1]["val_chamfer_mm2"], "r2_opening_train": calibration.r2_opening,
               "r2_gap_train": calibration.r2_gap, **{f"{k}_val": v for k, v in held_out.items()},
               "wall_time_s": time.perf_counter() - started}
    card = load_card(data_dir)
    info = {"data": {"path": str(Path(data_dir).resolve()), "name": card.name, "source": card.source,
                     "config_hash": card.config_hash, "clouds": int(len(clouds))},
            "train_config": asdict(train), "seed": train.seed, "code_version": code_version(),
            "metrics": metrics, "history": history}
    save_checkpoint(out_path, model, geometry_hash=geometry.geometry_hash,
                    registration_config=asdict(registration_config), calibration=calibration.to_dict(), info=info)
    return ToolEncoder(model, calibration, asdict(registration_config), info), metrics


__all__ = ["TrainEncoderConfig", "encode_all", "mean_chamfer_mm2", "recalibrate_encoder", "register_to_tool_frame",
           "surface_targets", "train_encoder"]
