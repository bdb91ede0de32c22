"""Steps 3 and 4 of the segmentation (`pipeline.segmentation`): the components of the joins
(union-find over row runs) and the merge of small components into the neighbour they share the
most refused pairs with. The edge bits of the join step's refusals are defined here.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

# Flags on a pair that does not join, kept for the merge (step 4): only the texture test refused
# it, or only the angle criterion refused a pair of one texture. Steps stay under 0x40.
TEXTURE_CUT = np.uint8(0x80)
ANGLE_CUT = np.uint8(0x40)
STEP_MASK = np.uint8(0x3F)


@njit(cache=True, inline="always")
def _find(parent, p):  # pragma: no cover - numba
    """Root of `p` in the union-find forest `parent` (path halving)."""
    while parent[p] != p:
        parent[p] = parent[parent[p]]
        p = parent[p]
    return p


@njit(cache=True, inline="always")
def _union(parent, a, b):  # pragma: no cover - numba
    ra = _find(parent, a)
    rb = _find(parent, b)
    if ra < rb:
        parent[rb] = ra
    elif rb < ra:
        parent[ra] = rb


@njit(cache=True)
def _number_sets(parent, weight):  # pragma: no cover - numba
    """The sets of the union-find forest `parent` (n,) numbered 0, 1, ... in the order of their
    first member: (n,) int32 number of each member, (count,) int32 sum of `weight` (n,) per set,
    count."""
    n = len(parent)
    number = np.full(n, -1, dtype=np.int32)
    sums = np.zeros(n, dtype=np.int32)
    count = 0
    for k in range(n):
        root = _find(parent, k)
        if number[root] < 0:
            number[root] = count
            count += 1
        number[k] = number[root]
        sums[number[k]] += weight[k]
    return number, sums[:count], count


@njit(cache=True, parallel=True)
def _label_components(ok, right, down):  # pragma: no cover - numba
    """Connected components of the join graph (joins flagged TEXTURE_CUT excluded): (H, W) int32
    ids numbered in raster order of each component's first pixel (-1 = not ok), (count,) int32
    pixel counts, count.

    1. Each row is cut into runs of pixels joined to their direct right-hand neighbour; rows in
       parallel, then each row's runs get consecutive ids in raster order.
    2. Vertical joins, and right joins that step over pixels or cross the seam, merge runs in a
       union-find forest.
    3. Runs are numbered in raster order of their first pixel, so components are too.
    """
    h, w = ok.shape
    run_of = np.empty((h, w), dtype=np.int32)  # the run of each ok pixel, as an id in its row
    row_len = np.empty((h, w), dtype=np.int32)  # pixel count of each row's k-th run
    row_runs = np.zeros(h, dtype=np.int32)
    for r in prange(h):
        n = 0
        c = 0
        while c < w:
            if not ok[r, c]:
                c += 1
                continue
            size = 1
            run_of[r, c] = n
            while c + 1 < w and right[r, c] == 1:
                c += 1
                run_of[r, c] = n
                size += 1
            row_len[r, n] = size
            n += 1
            c += 1
        row_runs[r] = n
    first = np.zeros(h + 1, dtype=np.int32)  # id of each row's first run
    for r in range(h):
        first[r + 1] = first[r] + row_runs[r]
    n = first[h]
    parent = np.arange(n, dtype=np.int32)
    length = np.empty(n, dtype=np.int32)
    for r in range(h):
        for k in range(row_runs[r]):
            length[first[r] + k] = row_len[r, k]
    for r in range(h):  # run ids stay per row in run_of: first[r] makes them global
        last_a = -1
        last_b = -1
        for c in range(w):
            d = right[r, c]
            if 0 < d < ANGLE_CUT and (d > 1 or c + 1 == w):
                c1 = c + d if c + d < w else c + d - w
                _union(parent, first[r] + run_of[r, c], first[r] + run_of[r, c1])
            d = down[r, c]
            if 0 < d < ANGLE_CUT:
                a = first[r] + run_of[r, c]
                b = first[r + d] + run_of[r + d, c]
                if a != last_a or b != last_b:  # neighbouring columns mostly join the same two runs
                    _union(parent, a, b)
                    last_a = a
                    last_b = b
    lab, sizes, count = _number_sets(parent, length)
    labels = np.full((h, w), -1, dtype=np.int32)
    for r in prange(h):
        for c in range(w):
            if ok[r, c]:
                labels[r, c] = lab[first[r] + run_of[r, c]]
    return labels, sizes, count


@njit(cache=True)
def _refused_pairs(labels, sizes, count, right, down, merge_pixels, tex, v_alpha, h_alpha):  # pragma: no cover
    """One pass over the image: the sorted int64 keys (small * count + other) * 4 + kind, one per
    refused pair of a small component and another, and (count,) bool the components taller than
    wide in angle by the bounding box of their pixels (a trunk, a pole; a piece of car body is
    wide).

    Kinds: 0 for pairs of rough pixels the angle criterion alone refused (pieces of one foliage
    mass), 1 for pairs the texture test alone refused, 2 and 3 for those of them that are vertical
    with the rough pixel above, 2 when the smooth one below belongs to the small component, 3 when
    it belongs to the other."""
    h, w = labels.shape
    keys = np.empty(4 * h * w, dtype=np.int64)
    r0 = np.full(count, h, dtype=np.int64)
    r1 = np.full(count, -1, dtype=np.int64)
    c0 = np.full(count, w, dtype=np.int64)
    c1 = np.full(count, -1, dtype=np.int64)
    m = 0
    for r in range(h):
        for c in range(w):
            a = labels[r, c]
            if a < 0:
                continue
            r0[a] = min(r0[a], r)
            r1[a] = r
            c0[a] = min(c0[a], c)
            c1[a] = max(c1[a], c)
            for side in range(2):
                flag = right[r, c] if side == 0 else down[r, c]
                if flag < ANGLE_CUT:
                    continue
                d = flag & STEP_MASK
                b = labels[r, (c + d) % w] if side == 0 else labels[r + d, c]
                if b == a or b < 0:
                    continue
                kind_a = kind_b = 0 if flag & ANGLE_CUT else 1
                if kind_a == 1 and side == 1 and tex[r, c] == 2:  # b is the smooth one below
                    kind_a, kind_b = 3, 2
                if sizes[a] < merge_pixels:
                    keys[m] = (a * count + b) * 4 + kind_a
                    m += 1
                if sizes[b] < merge_pixels:
                    keys[m] = (b * count + a) * 4 + kind_b
                    m += 1
    tall = np.zeros(count, dtype=np.bool_)
    for a in range(count):
        if r1[a] >= 0:
            tall[a] = (r1[a] - r0[a] + 1) * v_alpha[r0[a]] > (c1[a] - c0[a] + 1) * h_alpha
    return np.sort(keys[:m]), tall


@njit(cache=True)
def _partners(keys, count, tall):  # pragma: no cover - numba
    """(count,) int64 partner of each small component (-1 = none): the one it shares the most
    kind-0 pairs with, else the one it shares the most texture pairs with (ties: the lower id).
    Vertical texture pairs whose smooth lower component is tall do not count: a trunk does not
    join the crown above it, nor a piece of crown the trunk below it."""
    best = np.full((2, count), -1, dtype=np.int64)
    best_n = np.zeros((2, count), dtype=np.int64)
    m = keys.shape[0]
    i = 0
    while i < m:
        pair = keys[i] >> 2
        a = pair // count
        b = pair - a * count
        n_angle = 0
        n_texture = 0
        while i < m and keys[i] >> 2 == pair:
            kind = keys[i] & 3
            if kind == 0:
                n_angle += 1
            elif kind == 1 or not tall[a if kind == 2 else b]:
                n_texture += 1
            i += 1
        if n_angle > best_n[0, a]:
            best_n[0, a] = n_angle
            best[0, a] = b
        if n_texture > best_n[1, a]:
            best_n[1, a] = n_texture
            best[1, a] = b
    return np.where(best[0] >= 0, best[0], best[1])


@njit(cache=True)
def _merge_small(labels, sizes, count, right, down, merge_pixels, tex, v_alpha, h_alpha):  # pragma: no cover - numba
    """Step 4 of the module docstring: (count,) int32 merged id of each component (the merged
    ones numbered in raster order of their first pixel), their sizes, their count. The image is
    relabelled once, in `_finish`."""
    keys, tall = _refused_pairs(labels, sizes, count, right, down, merge_pixels, tex, v_alpha, h_alpha)
    best = _partners(keys, count, tall)
    parent = np.arange(count, dtype=np.int64)
    for a in np.argsort(sizes, kind="mergesort"):  # smallest first
        if sizes[a] >= merge_pixels:
            break
        if best[a] >= 0:
            _union(parent, a, best[a])
    return _number_sets(parent, sizes)  # components keep the raster order of their first pixel
