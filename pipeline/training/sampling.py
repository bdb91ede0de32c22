"""What each step draws: labelled samples (uniform or class-balanced), pairs (per pair, per component or
transitive over a track), and the labels spread over the must-link graph (closure labels)."""

from __future__ import annotations

import math

import numpy as np

from pipeline.config import TrainingConfig
from pipeline.training.data import TrainingData


class _Cycler:
    """Endless shuffled passes over range(n), drawn in chunks."""

    def __init__(self, n: int, rng: np.random.Generator) -> None:
        self.n, self.rng = n, rng
        self.order = rng.permutation(n)
        self.pos = 0

    def take(self, k: int) -> np.ndarray:
        out = []
        while k > 0:
            if self.pos == self.n:
                self.order, self.pos = self.rng.permutation(self.n), 0
            chunk = self.order[self.pos : self.pos + k]
            out.append(chunk)
            self.pos += len(chunk)
            k -= len(chunk)
        return np.concatenate(out)


class _BalancedCycler:
    """Labelled positions drawn class-uniformly: each draw picks a class present at random, then the
    next of that class's own shuffled passes."""

    def __init__(self, labels: np.ndarray, rng: np.random.Generator) -> None:
        self.rng = rng
        self.members = [np.flatnonzero(labels == k) for k in np.unique(labels)]
        self.cyclers = [_Cycler(len(m), rng) for m in self.members]

    def take(self, k: int) -> np.ndarray:
        cls = self.rng.integers(0, len(self.members), k)  # (k,)
        out = np.empty(k, np.int64)
        for c in np.unique(cls):
            sel = np.flatnonzero(cls == c)
            out[sel] = self.members[c][self.cyclers[c].take(len(sel))]
        return out


def must_link_components(pairs: np.ndarray, num_samples: int) -> tuple[int, np.ndarray]:
    """(number of components, (num_samples,) component id) of the must-link graph."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(num_samples, num_samples))
    n_comp, comp = connected_components(graph, directed=False)
    return int(n_comp), comp


def _closure(
    labelled: np.ndarray, labels: np.ndarray, pairs: np.ndarray, num_samples: int
) -> tuple[np.ndarray, np.ndarray, int, np.ndarray]:
    """closure_labels' result plus (L',) a group id per output sample: its component, or a group
    of its own for a labelled sample of a disagreeing component (which spreads to nothing)."""
    n_comp, comp = must_link_components(pairs, num_samples)
    lab_comp = comp[labelled]
    lo = np.full(n_comp, np.iinfo(np.int64).max)
    hi = np.full(n_comp, -1)
    np.minimum.at(lo, lab_comp, labels)
    np.maximum.at(hi, lab_comp, labels)
    agreed = hi >= 0  # components with a labelled member ...
    conflict = agreed & (lo != hi)
    agreed &= ~conflict  # ... whose labelled members all agree
    spread = np.flatnonzero(agreed[comp])  # every member of such a component
    keep = conflict[lab_comp]  # labelled samples of disagreeing components keep their own
    out_idx = np.concatenate([spread, labelled[keep]])
    out_lab = np.concatenate([hi[comp[spread]], labels[keep]])
    group = np.concatenate([comp[spread], n_comp + np.arange(int(keep.sum()))])
    order = np.argsort(out_idx, kind="stable")
    return out_idx[order], out_lab[order], int(conflict.sum()), group[order]


def closure_labels(
    labelled: np.ndarray, labels: np.ndarray, pairs: np.ndarray, num_samples: int
) -> tuple[np.ndarray, np.ndarray, int]:
    """(labelled', labels', conflicting components): the labels spread over the must-link graph.

    labelled (L,) indices, labels (L,) classes, pairs (P, 2) into 0..num_samples-1. Each connected
    component holding labelled samples of one class gives that class to all its members; a
    component whose labelled samples disagree keeps only those samples' own labels.
    """
    labelled = np.asarray(labelled, np.int64)
    labels = np.asarray(labels, np.int64)
    if len(pairs) == 0 or len(labelled) == 0:
        return labelled, labels, 0
    return _closure(labelled, labels, pairs, num_samples)[:3]


class _AnnotationDraw:
    """Labels via constraints drawn per annotation (`closure_draw="annotation"`): each draw picks
    one of the operator's annotations (class-uniformly with `balanced`), then a member of its
    component uniformly. Every annotation keeps the weight it has without constraints; drawing the
    closure's samples uniformly instead weights an annotation by its component's size, and since
    a long track is also the likelier to hold a drawn label, a class's few longest tracks take
    most of its draws (constraint30's bush: one component, 61 %)."""

    def __init__(self, annotation_pos: np.ndarray, annotation_labels: np.ndarray, group: np.ndarray,
                 balanced: bool, rng: np.random.Generator) -> None:
        # annotation_pos: (A,) positions of the annotations among the closure's samples;
        # group: (L',) group (component) id of each of the closure's samples
        self.rng = rng
        self.cycle: _Cycler | _BalancedCycler = (
            _BalancedCycler(annotation_labels, rng) if balanced else _Cycler(len(annotation_pos), rng))
        self.order = np.argsort(group, kind="stable")
        sorted_group = group[self.order]
        g = group[annotation_pos]
        self.start = np.searchsorted(sorted_group, g)  # (A,) first position of each annotation's group
        self.size = np.searchsorted(sorted_group, g, side="right") - self.start  # (A,) its group's size

    def take(self, k: int) -> np.ndarray:
        a = self.cycle.take(k)  # (k,) annotations
        return self.order[self.start[a] + self.rng.integers(0, self.size[a])]  # (k,) closure positions


class _ComponentDraw:
    """Pairs drawn per component (`pair_draw="component"`): each draw picks a component of the
    must-link graph uniformly, then one of the pairs inside it uniformly."""

    def __init__(self, pairs: np.ndarray, num_samples: int, rng: np.random.Generator) -> None:
        self.rng = rng
        _, comp = must_link_components(pairs, num_samples)
        pair_comp = comp[pairs[:, 0]]  # (P,)
        self.order = np.argsort(pair_comp, kind="stable")  # pairs grouped by component
        _, self.start, self.size = np.unique(pair_comp[self.order], return_index=True, return_counts=True)
        self.cycle = _Cycler(len(self.start), rng)

    def take(self, k: int) -> np.ndarray:
        c = self.cycle.take(k)  # (k,) components
        return self.order[self.start[c] + self.rng.integers(0, self.size[c])]  # (k,) pair indices


class _TrackPartners:
    """Must-link is an equivalence: every sample of a track (a connected component of the pair
    graph) has the same class. `draw(left)` gives each left sample a random other member of its
    component, so a pair can join a near and a far view of one object instead of two nearly equal
    consecutive frames."""

    def __init__(self, pairs: np.ndarray, num_samples: int, rng: np.random.Generator) -> None:
        self.rng = rng
        _, comp = must_link_components(pairs, num_samples)
        self.order = np.argsort(comp, kind="stable")  # (M,) samples grouped by component
        sorted_comp = comp[self.order]
        self.start = np.searchsorted(sorted_comp, comp)  # (M,) first position of each sample's component
        self.size = np.searchsorted(sorted_comp, comp, side="right") - self.start  # (M,) component sizes
        self.pos = np.empty(num_samples, np.int64)
        self.pos[self.order] = np.arange(num_samples)  # (M,) position of each sample in `order`

    def draw(self, left: np.ndarray) -> np.ndarray:
        """(n,) a member of each left sample's component other than itself (components have >= 2)."""
        size = self.size[left]
        off = self.rng.integers(0, np.maximum(size - 1, 1))  # (n,) in 0..size-2
        own = self.pos[left] - self.start[left]
        off = off + (off >= own)  # skip the left sample itself
        return self.order[self.start[left] + np.minimum(off, size - 1)]


class _BatchDraw:
    """What each step trains on: m labelled samples and n = pairs_per_label * m pairs."""

    def __init__(self, data: TrainingData, config: TrainingConfig,
                 annotations: tuple[np.ndarray, np.ndarray, np.ndarray] | None, rng: np.random.Generator) -> None:
        num_l, num_p = len(data.labelled), len(data.pairs)
        self.data = data
        self.m = min(config.batch_labelled, num_l)
        self.n = min(config.pairs_per_label * config.batch_labelled, num_p)
        if self.m == 0 and self.n == 0:  # constraints only with pairs_per_label = 0: m pairs per step instead
            self.n = min(config.batch_labelled, num_p)
        m, n = self.m, self.n
        steps = config.steps_per_epoch or max(math.ceil(num_l / m) if m else 0, math.ceil(num_p / n) if n else 0)
        self.steps = max(steps, 1)
        self.labels: _Cycler | _BalancedCycler | _AnnotationDraw | None = None
        if m and annotations is not None:
            self.labels = _AnnotationDraw(annotations[0], annotations[1], annotations[2], config.balanced_labels, rng)
        elif m:
            self.labels = _BalancedCycler(data.labels, rng) if config.balanced_labels else _Cycler(num_l, rng)
        self.pairs: _Cycler | _ComponentDraw | None = None
        if n:
            self.pairs = _ComponentDraw(data.pairs, len(data.samples), rng) if config.pair_draw == "component" \
                else _Cycler(num_p, rng)
        self.partners = _TrackPartners(data.pairs, len(data.samples), rng) if n and config.transitive_pairs else None

    def draw(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(li (m,) into labelled, pi (n,) into pairs, idx (m + 2n,) into samples: labelled, left, right)."""
        li = self.labels.take(self.m) if self.labels else np.zeros(0, np.int64)
        pi = self.pairs.take(self.n) if self.pairs else np.zeros(0, np.int64)
        left = self.data.pairs[pi, 0]
        right = self.partners.draw(left) if self.partners is not None else self.data.pairs[pi, 1]
        return li, pi, np.concatenate([self.data.labelled[li], left, right])
