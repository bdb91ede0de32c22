"""Training data: the labelled samples, the training pool with its must-link pairs, and the one seed helper."""

from __future__ import annotations

import random
from dataclasses import dataclass

import numpy as np
import torch

from pipeline.errors import DataError


def seed_everything(seed: int) -> None:
    """The one seed helper: Python, numpy and torch (CPU and CUDA), deterministic cuDNN."""
    random.seed(seed)
    np.random.seed(seed % 2**32)  # noqa: NPY002 - seeds code that uses the global numpy RNG
    torch.manual_seed(seed)
    torch.cuda.manual_seed_all(seed)
    torch.backends.cudnn.deterministic = True
    torch.backends.cudnn.benchmark = False


@dataclass(frozen=True)
class LabelledSamples:
    """samples: (M, C, S, S) uint8 canvases; labels: (M,) int64 class ids 0..K-1."""

    samples: np.ndarray
    labels: np.ndarray

    def __post_init__(self) -> None:
        assert self.samples.ndim == 4 and self.samples.dtype == np.uint8, (self.samples.dtype, self.samples.shape)
        assert self.labels.shape == (len(self.samples),), (self.labels.shape, len(self.samples))

    def __len__(self) -> int:
        return len(self.samples)


@dataclass(frozen=True)
class TrainingData:
    """The training pool: canvases, which of them are labelled, and must-link pairs among them.

    samples:      (M, C, S, S) uint8 canvases.
    labelled:     (L,) int64 indices into `samples` of the labelled samples.
    labels:       (L,) int64 class id (0..K-1) of each labelled sample.
    pairs:        (P, 2) int64 indices into `samples`: must-link constraints.
    pair_weights: (P,) float32 weight per pair: 1.0 verified, the association score for automatic pairs.
    """

    samples: np.ndarray
    labelled: np.ndarray
    labels: np.ndarray
    pairs: np.ndarray
    pair_weights: np.ndarray

    def __post_init__(self) -> None:
        m = len(self.samples)
        assert self.samples.ndim == 4 and self.samples.dtype == np.uint8, (self.samples.dtype, self.samples.shape)
        assert self.labelled.ndim == 1 and self.labels.shape == self.labelled.shape, (
            self.labelled.shape,
            self.labels.shape,
        )
        assert self.pairs.ndim == 2 and self.pairs.shape[1] == 2, self.pairs.shape
        assert self.pair_weights.shape == (len(self.pairs),), (self.pair_weights.shape, self.pairs.shape)
        for name, idx in (("labelled", self.labelled), ("pairs", self.pairs)):
            if idx.size and (idx.min() < 0 or idx.max() >= m):
                raise DataError(None, f"{name}: indices outside 0..{m - 1}")

    @classmethod
    def build(
        cls,
        samples: np.ndarray,
        labelled: np.ndarray | None = None,
        labels: np.ndarray | None = None,
        pairs: np.ndarray | None = None,
        pair_weights: np.ndarray | None = None,
    ) -> TrainingData:
        """Coerce dtypes; missing parts are empty (no labels / no pairs), pair weights default to 1."""
        lab = np.zeros(0, np.int64) if labelled is None else np.asarray(labelled, np.int64)
        y = np.zeros(0, np.int64) if labels is None else np.asarray(labels, np.int64)
        pr = np.zeros((0, 2), np.int64) if pairs is None else np.asarray(pairs, np.int64).reshape(-1, 2)
        w = np.ones(len(pr), np.float32) if pair_weights is None else np.asarray(pair_weights, np.float32)
        return cls(np.ascontiguousarray(samples), lab, y, pr, w)

    @classmethod
    def labelled_only(cls, data: LabelledSamples) -> TrainingData:
        return cls.build(data.samples, np.arange(len(data)), data.labels)
