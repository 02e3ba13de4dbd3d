"""The tool encoder: a PointNet VAE from a cloud in the canonical (tool) frame to a 2-D latent z.

PointNet (Qi et al. 2017): a shared per-point MLP (``widths``), max pooling over the points
(order invariant), an MLP head to the mean and log-variance of a diagonal Gaussian over z.
The decoder maps z to a cloud of ``decoder_points`` points; the loss is the Chamfer
distance to the clean surface cloud at the same opening plus ``beta`` times the KL
divergence to N(0, I) (so the low level's goals, drawn from N(0, I), land in the used range).

Frames and units: inputs are (B, N, 3) float32 metres in the tool frame (registered
clouds: ``Registration.to_tool_frame``); internally they are shifted by ``input_offset_m``
(the middle of the tool) and divided by ``scale_m``; decoder outputs are metres again.

Checkpoints (``save_checkpoint`` / ``load_encoder``) carry the format version, the config,
the registration config, the tool geometry's hash, the weights, the calibration, the
training data, seed, code version and metrics; a checkpoint that does not fit this code
or this tweezer is refused with one line saying why.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import json
import pickle
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch
from threadpoolctl import ThreadpoolController
from torch import nn

from hingelab.errors import ConfigError
from hingelab.paths import ASSETS_DIR
from hingelab.perception import encoder_kernels
from hingelab.perception.calibration import READER_FIELDS, OpeningCalibration
from hingelab.perception.clouds import ToolGeometry
from hingelab.perception.encoder_config import EncoderConfig
from hingelab.seeds import preserved_global_rngs

CHECKPOINT_FORMAT = "hingelab.tool_encoder"
CHECKPOINT_VERSION = 1
SHIPPED_CHECKPOINT = ASSETS_DIR / "checkpoints" / "encoder.pt"


def _mlp(widths: list[int]) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i, (a, b) in enumerate(zip(widths[:-1], widths[1:])):
        layers.append(nn.Linear(a, b))
        if i < len(widths) - 2:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)


class PointNetVAE(nn.Module):
    """encode: (B, N, 3) metres tool frame -> mu, logvar (B, latent); decode: z -> (B, M, 3) metres."""

    def __init__(self, config: EncoderConfig = EncoderConfig()):
        super().__init__()
        self.config = config
        c = config
        # shared per-point MLP: Linear layers on the last axis of (B, N, 3) (one GEMM per layer);
        # ReLU after the last layer too, before the max pool
        self.point_mlp = nn.Sequential(_mlp([3, *c.widths]), nn.ReLU())
        self.head = nn.Sequential(nn.Linear(c.widths[-1], c.head_width), nn.ReLU(),
                                  nn.Linear(c.head_width, 2 * c.latent_dim))
        self.decoder = nn.Sequential(_mlp([c.latent_dim, *c.decoder_widths]), nn.ReLU(),
                                     nn.Linear(c.decoder_widths[-1], 3 * c.decoder_points))
        self.register_buffer("offset", torch.tensor(c.input_offset_m, dtype=torch.float32))

    def encode(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        x = (points - self.offset) / self.config.scale_m  # (B, N, 3)
        feature = self.point_mlp(x).amax(dim=1)  # max pool over the points
        mu, logvar = self.head(feature).chunk(2, dim=1)
        # start nearly deterministic (sigma ~ 0.05): a decoder fed mostly noise at the start
        # learns to ignore z (posterior collapse); the KL term grows sigma as far as it pays
        return mu, (logvar + self.config.initial_logvar).clamp(-12.0, 6.0)

    def decode(self, z: torch.Tensor) -> torch.Tensor:
        out = self.decoder(z).view(len(z), self.config.decoder_points, 3)
        return out * self.config.scale_m + self.offset

    def forward(self, points: torch.Tensor, sample: bool = True, noise_scale: float = 1.0):
        mu, logvar = self.encode(points)
        z = mu + noise_scale * torch.randn_like(mu) * (0.5 * logvar).exp() if sample else mu
        return self.decode(z), mu, logvar


def chamfer(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Symmetric Chamfer distance per cloud: mean squared nearest distance a->b plus b->a. (B,)"""
    d = torch.cdist(a, b).square()
    return d.min(dim=2).values.mean(dim=1) + d.min(dim=1).values.mean(dim=1)


def vae_loss(model: PointNetVAE, points: torch.Tensor, target: torch.Tensor, beta_scale: float = 1.0):
    """(loss, chamfer in scaled units^2, KL) averaged over the batch; the KL weight is
    ``beta * beta_scale`` (training ramps beta_scale up from 0 so the latent is used)."""
    # the sampling noise ramps up with beta: an autoencoder first, so the decoder learns to
    # listen to z before the noise could teach it to ignore z (posterior collapse)
    recon, mu, logvar = model(points, noise_scale=beta_scale)
    scale = model.config.scale_m
    rec = chamfer(recon / scale, target / scale).mean()
    kl = (-0.5 * (1 + logvar - mu.square() - logvar.exp()).sum(dim=1)).mean()
    return rec + model.config.beta * beta_scale * kl, rec, kl


# An env encodes one cloud per step. Two threads on so small a product only wait on each
# other, and in env worker processes (SubprocVecEnv, one per core) each worker's pool spins
# against the others' and slows every worker down several times over (measured in
# analysis/bench/history/README.md). Batches up to this size run in numpy on one OpenBLAS
# thread (``_small_batch_latent_mean``), larger ones in torch.
ONE_THREAD_BATCH = 8


@contextlib.contextmanager
def one_torch_thread():
    """Run the block on one torch intra-op thread, then restore the caller's setting."""
    threads = torch.get_num_threads()
    if threads == 1:
        yield
        return
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


@functools.cache
def _openblas():
    """numpy's OpenBLAS thread control (threadpoolctl), or None where numpy uses another BLAS."""
    found = [c for c in ThreadpoolController().lib_controllers if c.internal_api == "openblas"]
    # scipy may load an OpenBLAS of its own: numpy's is the one in numpy's wheel folder
    numpys = [c for c in found if "numpy" in Path(c.filepath).parent.name]
    return (numpys or found or [None])[0]


@contextlib.contextmanager
def one_blas_thread():
    """Run the block on one OpenBLAS thread, then restore the caller's setting (a few microseconds:
    the controller is looked up once; threadpoolctl's own context manager looks it up every time)."""
    blas = _openblas()
    threads = blas.get_num_threads() if blas is not None else 1
    if threads == 1:
        yield
        return
    blas.set_num_threads(1)
    try:
        yield
    finally:
        blas.set_num_threads(threads)


class ToolEncoder:
    """A trained encoder ready to use: ``encode(points_tool) -> z`` (numpy in, numpy out).

    Attributes: model (PointNetVAE, eval mode), calibration (OpeningCalibration or None),
    registration_config (dict, what the training clouds were registered with), info (the
    checkpoint's provenance: data, seed, code version, metrics). The weights are read once
    (the fingerprint, the numpy copy for small batches): wrap a trained model, do not train it
    through this object.
    """

    def __init__(self, model: PointNetVAE, calibration=None, registration_config: dict | None = None,
                 info: dict | None = None):
        self.model = model.eval()
        self.calibration = calibration
        self.registration_config = registration_config or {}
        self.info = info or {}

    @functools.cached_property
    def fingerprint(self) -> str:
        """16 hex digits of a hash of the weights and the calibration: what a latent means.

        A low-level policy records the fingerprint of the encoder whose latents it learned
        from, and is refused beside another one (its goals and inputs would mean other openings).
        """
        digest = hashlib.sha256()
        for name, tensor in sorted(self.model.state_dict().items()):
            digest.update(name.encode())
            digest.update(tensor.detach().cpu().numpy().tobytes())
        if self.calibration is not None:  # the curve, not the reader (it changes no latent and no goal)
            curve = {k: v for k, v in self.calibration.to_dict().items() if k not in READER_FIELDS}
            digest.update(json.dumps(curve, sort_keys=True).encode())
        return digest.hexdigest()[:16]

    def accepts(self, fingerprint: str) -> bool:
        """Whether a policy that learned beside the encoder ``fingerprint`` reads this one's latents:
        this fingerprint, or one its calibration curve replaced (the same weights,
        ``hingelab.perception.sim_calibration``)."""
        return fingerprint == self.fingerprint or fingerprint in (self.info.get("curve") or {}).get("replaces", ())

    def encode(self, points_tool: np.ndarray) -> np.ndarray:
        """(B, N, 3) or (N, 3) metres, tool frame -> latent means z (B, 2) or (2,) float64."""
        arr = np.asarray(points_tool, dtype=np.float32)
        single = arr.ndim == 2
        if arr.ndim not in (2, 3) or arr.shape[-1] != 3:
            raise ConfigError(f"the encoder takes clouds of shape (N, 3) or (B, N, 3), got {arr.shape}")
        if not np.isfinite(arr).all():
            raise ConfigError("a cloud given to the encoder has NaN or Inf coordinates")
        batch = arr[None] if single else arr
        offset, scale = self.input_offset_and_scale
        z = self.encode_scaled((batch - offset) / scale)
        return z[0] if single else z

    @functools.cached_property
    def input_offset_and_scale(self) -> tuple[np.ndarray, np.float32]:
        """(offset (3,) float32 m, scale float32 m): the network reads points as (p - offset) / scale."""
        return self.model.offset.numpy().copy(), np.float32(self.model.config.scale_m)

    def encode_scaled(self, scaled: np.ndarray) -> np.ndarray:
        """``encode`` of clouds already moved and scaled as the network reads them: (B, N, 3)
        float32, finite, ``(p - offset) / scale`` of tool-frame points (``input_offset_and_scale``)
        -> z (B, 2) float64. For callers that compute that input in their own compiled pass."""
        if len(scaled) <= ONE_THREAD_BATCH:
            with one_blas_thread():
                return self._small_batch_latent_mean(scaled)
        with torch.no_grad():
            return self._latent_mean(torch.from_numpy(np.ascontiguousarray(scaled))).double().numpy()

    @functools.cached_property
    def _layers(self):
        """The Linear layers of the point MLP and of the head (the same parameter tensors)."""
        def linears(module):
            return [layer for layer in module.modules() if isinstance(layer, nn.Linear)]
        return linears(self.model.point_mlp), linears(self.model.head)

    @functools.cached_property
    def _numpy_layers(self):
        """float32 (weight^T, bias) of the point MLP's and the head's Linear layers:
        ``_small_batch_latent_mean``'s copy of the weights."""
        point_layers, head_layers = self._layers

        def arrays(layer):
            return (layer.weight.detach().numpy().T.copy(), layer.bias.detach().numpy().copy())
        return [arrays(layer) for layer in point_layers], [arrays(layer) for layer in head_layers]

    def _small_batch_latent_mean(self, scaled: np.ndarray) -> np.ndarray:
        """``_latent_mean`` in numpy for a few scaled clouds (B, N, 3) float32 -> (B, 2) float64.
        For one cloud per env step torch's per-call cost and its slower kernel on this CPU are a
        large share of the encoding; OpenBLAS on one thread does the products at its peak rate.
        The last point layer's ReLU comes after the max pool: max_i relu(x_i + b) = relu(max_i x_i
        + b), exactly. Bias and ReLU are one compiled pass over each layer's output (the same
        float32 operations as numpy's). The same numbers as torch to float32 rounding (~1e-7)."""
        point_layers, (head_in, head_out) = self._numpy_layers
        out = np.empty((len(scaled), self.model.config.latent_dim))
        for b, x in enumerate(scaled):
            for weight, bias in point_layers[:-1]:
                x = x @ weight
                encoder_kernels.add_bias_relu(x, bias)
            weight, bias = point_layers[-1]
            feature = encoder_kernels.max_pool_bias_relu(x @ weight, bias)
            hidden = np.maximum(feature @ head_in[0] + head_in[1], 0.0)
            out[b] = (hidden @ head_out[0] + head_out[1])[:self.model.config.latent_dim]
        return out

    def _latent_mean(self, scaled: torch.Tensor) -> torch.Tensor:
        """``PointNetVAE.encode``'s mean of scaled clouds (B, N, 3) without nn.Module dispatch (a
        noticeable share of an env step's encode): ReLU after every point layer, max pool, head; the
        same numbers."""
        point_layers, (head_in, head_out) = self._layers
        x = scaled
        for layer in point_layers:
            x = torch.relu(nn.functional.linear(x, layer.weight, layer.bias))
        hidden = torch.relu(nn.functional.linear(x.amax(dim=1), head_in.weight, head_in.bias))
        return nn.functional.linear(hidden, head_out.weight, head_out.bias)[:, :self.model.config.latent_dim]

    @torch.no_grad()
    def decode(self, z: np.ndarray) -> np.ndarray:
        """Latents (B, 2) -> decoded clouds (B, M, 3) metres, tool frame."""
        return self.model.decode(torch.as_tensor(np.atleast_2d(z), dtype=torch.float32)).numpy()


def save_checkpoint(path, model: PointNetVAE, *, geometry_hash: str, registration_config: dict,
                    calibration: dict | None, info: dict) -> Path:
    """Write a checkpoint (atomically: a temporary name, then a rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {
        "format": CHECKPOINT_FORMAT, "format_version": CHECKPOINT_VERSION,
        "config": asdict(model.config), "geometry_hash": geometry_hash,
        "registration_config": registration_config, "calibration": calibration,
        "state_dict": model.state_dict(), **info,
    }
    tmp = path.with_name(path.name + ".tmp")
    torch.save(plain_payload(payload), tmp)
    tmp.replace(path)
    return path


def plain_payload(value):
    """``value`` with tensors and plain Python values only (numpy scalars and arrays made plain), so
    ``torch.load(weights_only=True)`` reads it back without unpickling any other object."""
    if isinstance(value, torch.Tensor):
        return value
    if isinstance(value, dict):
        return {str(k): plain_payload(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain_payload(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return torch.from_numpy(np.ascontiguousarray(value))
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    raise TypeError(f"an encoder checkpoint holds tensors and plain values only, not {type(value).__name__}")


def rewrite_calibration(path, encoder: ToolEncoder, calibration: dict, **records) -> ToolEncoder:
    """Write ``encoder`` (its weights, registration config and provenance) to ``path`` with another
    calibration and more provenance ``records`` (e.g. ``reader=...``), and load it back."""
    info = {k: v for k, v in encoder.info.items()
            if k not in ("format", "format_version", "geometry_hash", "registration_config")}
    save_checkpoint(path, encoder.model, geometry_hash=ToolGeometry.default().geometry_hash,
                    registration_config=encoder.registration_config, calibration=calibration,
                    info={**info, **records})
    return load_encoder(path)


def load_encoder(path=None, geometry=None) -> ToolEncoder:
    """Load a checkpoint (default: the shipped ``assets/checkpoints/encoder.pt``) and check it fits.

    Refused with a one-line ``ConfigError``: a missing or unreadable file, another format or
    format version, an encoder config this code does not know, weights that do not fit the
    config, or a tweezer geometry other than the current model's; a file holding pickled objects
    besides tensors and plain values (read with ``weights_only=True``, nothing of it runs).
    """
    path = Path(path or SHIPPED_CHECKPOINT)
    if not path.exists():
        raise ConfigError(f"encoder checkpoint {path} does not exist; train one with `hingelab train encoder`")
    try:  # weights_only: tensors and plain values; any other pickled object is refused unread
        raw = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        if "global" not in str(exc).lower():  # no object torch refused to import: a broken file
            raise ConfigError(f"{path} is not a readable torch checkpoint (UnpicklingError)") from exc
        raise ConfigError(f"{path} holds Python objects besides tensors and plain values, so it was not loaded "
                          "(loading it could run code); if it is a trusted checkpoint from an older hingelab, "
                          f"convert it with `hingelab checkpoints convert {path}`") from exc
    except Exception as exc:  # torch raises many kinds on a bad file
        raise ConfigError(f"{path} is not a readable torch checkpoint ({type(exc).__name__}: "
                          f"{str(exc).splitlines()[0] if str(exc) else ''})") from exc
    return _encoder_from_raw(raw, path, geometry)


def _encoder_from_raw(raw, path: Path, geometry=None) -> ToolEncoder:
    if not isinstance(raw, dict) or raw.get("format") != CHECKPOINT_FORMAT:
        raise ConfigError(f"{path} is not a hingelab tool-encoder checkpoint (format "
                          f"{raw.get('format') if isinstance(raw, dict) else type(raw).__name__!r})")
    if raw.get("format_version") != CHECKPOINT_VERSION:
        raise ConfigError(f"{path} has encoder checkpoint format {raw.get('format_version')}, this hingelab reads "
                          f"{CHECKPOINT_VERSION}; retrain with `hingelab train encoder` or use a matching hingelab")
    config = EncoderConfig.from_dict(raw.get("config") or {}, source=str(path))
    geometry = geometry or ToolGeometry.default()
    if raw.get("geometry_hash") != geometry.geometry_hash:
        raise ConfigError(f"{path} was trained on another tweezer geometry ({raw.get('geometry_hash')}, now "
                          f"{geometry.geometry_hash}); regenerate the clouds and retrain the encoder")
    with preserved_global_rngs():  # the initial weights are overwritten: loading draws nothing of a run's
        model = PointNetVAE(config)
    try:
        model.load_state_dict(raw["state_dict"])
    except (RuntimeError, KeyError) as exc:
        raise ConfigError(f"{path}: weights do not fit the encoder config ({str(exc).splitlines()[0]})") from exc
    calibration = OpeningCalibration.from_dict(raw["calibration"]) if raw.get("calibration") else None
    info = {k: v for k, v in raw.items() if k not in ("state_dict", "config", "calibration")}
    return ToolEncoder(model, calibration, raw.get("registration_config"), info)


def convert_checkpoint(path) -> tuple[str, bool]:
    """Rewrite a trusted checkpoint of an older hingelab with tensors and plain values only, so it loads
    with ``weights_only=True``: (its fingerprint, whether it was rewritten). Reading the old file runs its
    pickle: call this only on files you trust (``hingelab checkpoints convert`` is that decision)."""
    path = Path(path)
    try:
        torch.load(path, map_location="cpu", weights_only=True)
        return load_encoder(path).fingerprint, False
    except pickle.UnpicklingError:
        pass
    raw = torch.load(path, map_location="cpu", weights_only=False)  # trusted by the caller
    before = _encoder_from_raw(raw, path).fingerprint
    tmp = path.with_name(path.name + ".converting")
    torch.save(plain_payload(raw), tmp)
    try:
        after = load_encoder(tmp).fingerprint
        if after != before:
            raise ConfigError(f"{path}: the plain rewrite changed the encoder's fingerprint ({before} -> {after}); "
                              "left unconverted")
    except Exception:
        tmp.unlink(missing_ok=True)
        raise
    tmp.replace(path)
    return after, True


@functools.cache
def shipped_encoder() -> ToolEncoder:
    """The shipped checkpoint, loaded once per process."""
    return load_encoder()


def shipped_encoder_fingerprint() -> str:
    """``ToolEncoder.fingerprint`` of the shipped checkpoint."""
    return shipped_encoder().fingerprint


__all__ = ["CHECKPOINT_FORMAT", "CHECKPOINT_VERSION", "EncoderConfig", "PointNetVAE", "SHIPPED_CHECKPOINT",
           "ToolEncoder", "chamfer", "load_encoder", "one_blas_thread", "one_torch_thread", "rewrite_calibration",
           "convert_checkpoint", "plain_payload", "save_checkpoint",
           "shipped_encoder", "shipped_encoder_fingerprint", "vae_loss"]
