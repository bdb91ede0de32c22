"""The train / validation split by group (track or ground-truth object)."""

from __future__ import annotations

import numpy as np


def split_by_group(
    labels: np.ndarray, groups: np.ndarray, val_fraction: float, seed: int | np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """(train, val) int64 indices into `labels` (L,) whose samples belong to `groups` (L,): the
    track of each sample (the train job) or its ground-truth object (the simulated experiments,
    where an object's several tracks would otherwise land on both sides); `seed` may be a
    generator to draw from (its state advances).

    Whole groups go to one side: the samples of one track or object are near-duplicates, so a
    split of samples would validate on copies of training samples. Per class present,
    round(val_fraction x its groups) groups go to validation, never all of them; a group holding
    samples of several classes goes to validation when any of its classes sends it there.
    """
    rng = np.random.default_rng(seed)
    labels, groups = np.asarray(labels), np.asarray(groups)
    val_groups = []
    for k in np.unique(labels):
        cand = np.unique(groups[labels == k])
        cand = cand[rng.permutation(len(cand))]
        n_val = int(round(len(cand) * val_fraction))
        val_groups.append(cand[: min(n_val, max(len(cand) - 1, 0))])
    vg = np.concatenate(val_groups) if val_groups else np.zeros(0, groups.dtype)
    in_val = np.isin(groups, vg)
    return np.flatnonzero(~in_val).astype(np.int64), np.flatnonzero(in_val).astype(np.int64)
