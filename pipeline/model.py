"""The sample classifier: a compact CNN over the (C, S, S) sample canvas giving K class logits.

Used as a siamese pair with shared weights: training runs one forward over the concatenation
of labelled samples and both sides of the constraint pairs (`pipeline.training`).
Inference needs this module only: `load_checkpoint` rebuilds the model from a checkpoint,
`predict` turns uint8 canvases into class probabilities and `embed` into feature vectors.

Architecture (nanoGPT style, one dataclass config)::

    depth x [conv3x3 -> BN -> ReLU -> maxpool 2]   channels width, 2 width, ... capped at max_width
    global average pool -> dropout -> linear K

The first conv has stride `stem_stride` (2 by default): the canvases repeat each laser ring over
several rows, so full resolution in the first block costs 5-7x the CPU time for little. Global
pooling makes the same network run on S=64 and S=256 canvases. Activations are channels-last,
which is about 1.5x faster on CPU.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from pipeline.classes import NUM_SAMPLE_CLASSES, SAMPLE_CLASSES
from pipeline.config import ModelConfig, SampleConfig, TrainingConfig
from pipeline.errors import ConfigError, DataError, LabelSetMismatch
from pipeline.label_sets import DEFAULT_LABEL_SET, LabelSet

CHECKPOINT_FORMAT = "tracklabel-cnn/1"


@dataclass(frozen=True)
class NetConfig:
    """Everything needed to build the network; stored in every checkpoint."""

    in_channels: int = 4  # C: 3 (height, range, intensity) or 4 (+ foreground mask)
    size: int = 64  # S: canvas side; any S divisible by 2**depth works (global pooling)
    num_classes: int = NUM_SAMPLE_CLASSES  # K
    width: int = 32  # channels of the first block
    max_width: int = 128  # channel cap of later blocks
    depth: int = 4  # conv blocks, each halving the resolution
    stem_stride: int = 2  # stride of the first conv
    dropout: float = 0.3

    @classmethod
    def from_configs(cls, model: ModelConfig, samples: SampleConfig) -> NetConfig:
        return cls(
            in_channels=samples.channels,
            size=samples.size,
            num_classes=model.num_classes,
            width=model.width,
            max_width=model.max_width,
            depth=model.depth,
            stem_stride=model.stem_stride,
            dropout=model.dropout,
        )

    def block_channels(self) -> list[int]:
        return [min(self.width * 2**i, self.max_width) for i in range(self.depth)]


class SampleCNN(nn.Module):
    def __init__(self, config: NetConfig) -> None:
        super().__init__()
        factor = config.stem_stride * 2**config.depth
        if config.size % factor:
            raise ValueError(f"canvas size {config.size} is not divisible by stem_stride * 2**depth = {factor}")
        self.config = config
        layers: list[nn.Module] = []
        c_in = config.in_channels
        for i, c_out in enumerate(config.block_channels()):
            stride = config.stem_stride if i == 0 else 1
            layers += [
                nn.Conv2d(c_in, c_out, kernel_size=3, stride=stride, padding=1, bias=False),
                nn.BatchNorm2d(c_out),
                nn.ReLU(inplace=True),
                nn.MaxPool2d(2),
            ]
            c_in = c_out
        self.body = nn.Sequential(*layers)
        self.dropout = nn.Dropout(config.dropout)
        self.head = nn.Linear(c_in, config.num_classes)
        self.feature_dim = c_in
        self.to(memory_format=torch.channels_last)

    def features(self, x: torch.Tensor) -> torch.Tensor:
        """Embeddings (B, D) of float canvases (B, C, S, S) in [0, 1]."""
        assert x.ndim == 4 and x.shape[1] == self.config.in_channels, x.shape
        x = x.contiguous(memory_format=torch.channels_last)  # (B, C, S, S), stored NHWC
        h = self.body(x)  # (B, D, S / (stem_stride 2**depth), same)
        return h.mean(dim=(2, 3))  # (B, D): global average pool

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Logits (B, K) of float canvases (B, C, S, S) in [0, 1]."""
        return self.head(self.dropout(self.features(x)))  # (B, K)

    def num_parameters(self) -> int:
        return sum(p.numel() for p in self.parameters())


def build_model(config: NetConfig) -> SampleCNN:
    return SampleCNN(config)


def get_model(model: ModelConfig, samples: SampleConfig) -> SampleCNN:
    """A fresh network for canvases of `samples` (the config-tree factory)."""
    return build_model(NetConfig.from_configs(model, samples))


def resolve_device(name: str = "auto") -> torch.device:
    """`auto` = CUDA when present, else CPU; `cpu` / `cuda` / `cuda:N` as given."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        device = torch.device(name)
    except RuntimeError:
        raise ConfigError(f"unknown device {name!r}: use auto, cpu or cuda (cuda:N)") from None
    if device.type == "cuda" and not torch.cuda.is_available():
        build = f"this PyTorch {torch.__version__} is a CPU build" if torch.version.cuda is None else (
            f"this PyTorch {torch.__version__} (CUDA {torch.version.cuda}) finds no CUDA device")
        raise ConfigError(f"device {name!r}: {build}; use --device cpu, or install a CUDA wheel of torch "
                          "(README, Install)")
    return device


def to_input(batch: torch.Tensor) -> torch.Tensor:
    """uint8 canvases (B, C, S, S) -> float32 in [0, 1], same shape."""
    return batch.float().div_(255.0)


def _check_samples(samples: np.ndarray, config: NetConfig) -> None:
    if samples.ndim != 4 or samples.shape[1] != config.in_channels or samples.dtype != np.uint8:
        raise DataError(
            None,
            f"samples: expected uint8 (M, {config.in_channels}, S, S), got {samples.dtype} {samples.shape}",
        )


@torch.no_grad()
def _batched(model: SampleCNN, samples: np.ndarray, batch: int, fn: str) -> np.ndarray:
    _check_samples(samples, model.config)
    device = next(model.parameters()).device
    was_training = model.training
    model.eval()
    out = []
    try:
        for start in range(0, len(samples), batch):
            x = to_input(torch.from_numpy(samples[start : start + batch]).to(device))  # (b, C, S, S)
            if fn == "probs":
                out.append(torch.softmax(model(x), dim=1).cpu().numpy())  # (b, K)
            else:
                out.append(model.features(x).cpu().numpy())  # (b, D)
    finally:
        model.train(was_training)
    width = model.config.num_classes if fn == "probs" else model.feature_dim
    return np.concatenate(out).astype(np.float32) if out else np.zeros((0, width), np.float32)


def predict(model: SampleCNN, samples: np.ndarray, batch: int = 256) -> np.ndarray:
    """Class probabilities (M, K) float32 of uint8 canvases (M, C, S, S), in eval mode."""
    return _batched(model, samples, batch, "probs")


def embed(model: SampleCNN, samples: np.ndarray, batch: int = 256) -> np.ndarray:
    """Feature vectors (M, D) float32 of uint8 canvases (M, C, S, S), e.g. for k-center anchors."""
    return _batched(model, samples, batch, "features")


@dataclass(frozen=True)
class CheckpointMeta:
    """What a checkpoint says about itself besides the weights."""

    net: NetConfig
    model_config: ModelConfig
    sample_config: SampleConfig
    classes: tuple[str, ...]
    metrics: dict[str, Any] = field(default_factory=dict)
    training_config: TrainingConfig | None = None
    # statistics of the training inputs (`pipeline.input_stats`), {} for older checkpoints
    input_stats: dict[str, Any] = field(default_factory=dict)
    # the label set the model was trained on; checkpoints written before label sets were paper's
    label_set: str = DEFAULT_LABEL_SET


def save_checkpoint(
    path: str | Path,
    model: SampleCNN,
    model_config: ModelConfig,
    sample_config: SampleConfig,
    metrics: dict[str, Any] | None = None,
    training_config: TrainingConfig | None = None,
    classes: tuple[str, ...] = SAMPLE_CLASSES,
    input_stats: dict[str, Any] | None = None,
    label_set: str = DEFAULT_LABEL_SET,
) -> Path:
    """Write a self-describing checkpoint (plain types + tensors, loadable with weights_only);
    `input_stats`: statistics of the training inputs (`pipeline.input_stats`) that predict
    compares a sequence's inputs with; `label_set`: the name of the set `classes` come from."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {
        "format": CHECKPOINT_FORMAT,
        "net": asdict(model.config),
        "model_config": model_config.model_dump(mode="json"),
        "sample_config": sample_config.model_dump(mode="json"),
        "training_config": None if training_config is None else training_config.model_dump(mode="json"),
        "label_set": label_set,
        "classes": list(classes),
        "metrics": metrics or {},
        "input_stats": input_stats or {},
        "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()},
    }
    tmp = path.with_name(path.name + ".tmp")
    torch.save(payload, tmp)
    tmp.replace(path)
    return path


def load_checkpoint(path: str | Path, device: str | torch.device = "cpu") -> tuple[SampleCNN, CheckpointMeta]:
    """Rebuild the model (eval mode, on `device`) and its metadata from a checkpoint file."""
    path = Path(path)
    if not path.is_file():
        raise DataError(path, "checkpoint not found")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types for corrupt files
        # torch's own text advises weights_only=False, which would run a corrupt file's pickle
        raise DataError(path, f"cannot read checkpoint: the file is corrupt, truncated or not a "
                        f"tracklabel checkpoint ({type(exc).__name__})") from exc
    if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT:
        raise DataError(path, f"not a {CHECKPOINT_FORMAT} checkpoint")
    try:
        net = NetConfig(**payload["net"])
        meta = CheckpointMeta(
            net=net,
            model_config=ModelConfig.model_validate(payload["model_config"]),
            sample_config=_sample_config(payload["sample_config"]),
            classes=tuple(payload["classes"]),
            metrics=dict(payload.get("metrics") or {}),
            training_config=None
            if payload.get("training_config") is None
            else _training_config(payload["training_config"]),
            input_stats=dict(payload.get("input_stats") or {}),
            label_set=str(payload.get("label_set") or DEFAULT_LABEL_SET),
        )
        model = build_model(net)
        model.load_state_dict(payload["state_dict"])
    except (KeyError, TypeError, ValueError, RuntimeError) as exc:
        raise DataError(path, f"inconsistent checkpoint: {exc}") from exc
    model.to(resolve_device(str(device)) if isinstance(device, str) else device)
    model.eval()
    return model, meta


def check_label_set(meta: CheckpointMeta, label_set: LabelSet, path: str | Path) -> None:
    """LabelSetMismatch unless the checkpoint at `path` was trained on `label_set`: the same
    name and the same sample classes, in order (its outputs are those classes)."""
    if meta.label_set == label_set.name and tuple(meta.classes) == label_set.sample_class_names:
        return
    raise LabelSetMismatch(
        f"{path}: the model was trained on label set {meta.label_set!r} ({', '.join(meta.classes)}), "
        f"not on {label_set.name!r} ({', '.join(label_set.sample_class_names)}): use a model of "
        f"{label_set.name!r}, or ask for label set {meta.label_set!r}"
    )


def _sample_config(stored: dict[str, Any]) -> SampleConfig:
    """A checkpoint's sample config; one written before intensity was normalised per sensor
    read raw intensities (its model knows no other)."""
    return SampleConfig.model_validate({"intensity": "raw", **stored})


def _training_config(stored: dict[str, Any]) -> TrainingConfig:
    """A checkpoint's training config; options removed since it was written (gamma_rampup,
    component_power) are dropped so that older checkpoints still load."""
    return TrainingConfig.model_validate({k: v for k, v in stored.items() if k in TrainingConfig.model_fields})


# The model shipped with the package: trained on the simulated campus by
# `tracklabel experiment default-model --out pipeline/models/default.pt` (pipeline/models/default.json
# says on what and what it scored). Used when no model is given or registered.
DEFAULT_MODEL = Path(__file__).resolve().parent / "models" / "default.pt"


def default_model_path() -> Path:
    """The shipped default checkpoint; a ConfigError when this installation lacks it."""
    if not DEFAULT_MODEL.is_file():
        raise ConfigError(f"no default model at {DEFAULT_MODEL}: train one (tracklabel experiment default-model)")
    return DEFAULT_MODEL
