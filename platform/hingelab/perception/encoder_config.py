"""The tool encoder's settings: its architecture and loss (``EncoderConfig``, a checkpoint must match it) and how
it is trained (``TrainEncoderConfig``). Plain dataclasses: ``hingelab train encoder``'s flags take their defaults
from here without loading torch (``hingelab.perception.encoder`` and ``train_encoder`` use them)."""

from __future__ import annotations

from dataclasses import dataclass, fields

from hingelab.errors import ConfigError


@dataclass(frozen=True)
class EncoderConfig:
    """Architecture and loss of the PointNet VAE (a checkpoint must match it exactly)."""

    latent_dim: int = 2
    widths: tuple[int, ...] = (64, 128, 256)  # shared per-point MLP
    head_width: int = 128  # MLP after max pooling
    decoder_widths: tuple[int, ...] = (128, 256)
    decoder_points: int = 256
    input_offset_m: tuple[float, float, float] = (0.06, 0.0, 0.0)  # middle of the tool, tool frame
    scale_m: float = 0.05  # coordinates are divided by this
    beta: float = 0.0001  # KL weight (Chamfer is in scaled units squared; 1e-3 collapses the latent)
    target_points: int = 512  # clean surface points the reconstruction is compared with
    initial_logvar: float = -6.0  # offset of the encoder's log-variance output

    @classmethod
    def from_dict(cls, raw: dict, source: str = "checkpoint") -> "EncoderConfig":
        names = {f.name for f in fields(cls)}
        unknown, missing = set(raw) - names, names - set(raw)
        if unknown or missing:
            raise ConfigError(f"{source}: encoder config does not match this hingelab version "
                              f"(unknown {sorted(unknown)}, missing {sorted(missing)}); retrain with "
                              "`hingelab train encoder`")
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in raw.items()})


@dataclass(frozen=True)
class TrainEncoderConfig:
    """Training settings (recorded in the checkpoint)."""

    epochs: int = 18
    batch_size: int = 64
    kl_warmup_fraction: float = 0.3  # beta ramps up linearly over this fraction of the steps
    augment_angle_deg: float = 0.0  # random turn of each input cloud per step, per Euler angle
    augment_offset_m: float = 0.0  # random shift of each input cloud per step, per axis
    learning_rate: float = 1e-3
    seed: int = 0
    val_fraction: float = 0.1  # the last episodes, held out
    threads: int = 2  # torch CPU threads
    register_batch: int = 250  # clouds registered at once
