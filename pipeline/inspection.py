"""`inspect_sequence`: what a sequence holds, read frame by frame (what `tracklabel inspect` prints).

The sequence is opened as `tracklabel process` opens it (`pipeline.sequence.open_sequence`), so the
sensor shown, its beams and columns and how it was decided are the ones processing uses.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipeline.label_sets import DEFAULT_LABEL_SET, UNLABELLED, LabelSet, preset
from pipeline.scan import SequenceInfo, SequenceSource
from pipeline.sequence import open_sequence


def pose_status(source: SequenceSource) -> str:
    """`given` when the source has poses, `estimable` when ICP can estimate them (>= 2 frames)."""
    if source.poses is not None:
        return "given"
    return "estimable" if len(source) >= 2 else "absent"


def inspect_sequence(path: str | Path, fmt: str = "auto", sensor: str = "auto",
                     label_set: LabelSet | None = None) -> SequenceInfo:
    """Open and read every frame of `path`, its labels counted in `label_set`'s classes (the
    default set's when None); raises DataError naming the first bad file."""
    label_set = label_set or preset(DEFAULT_LABEL_SET)
    table = label_set.to_index_table()
    opened = open_sequence(path, fmt, sensor=sensor)
    source = opened.source
    n = len(source)
    counts = np.zeros(n, dtype=np.int64)
    dropped = 0
    histogram = np.zeros(256, dtype=np.int64)
    labelled = False
    for i in range(n):
        scan = source.frame(i)
        counts[i] = len(scan)
        dropped += scan.dropped
        if scan.semantic is not None:
            labelled = True
            histogram += np.bincount(table[scan.semantic.astype(np.int64) & 0xFFFF], minlength=256)
    warnings = list(getattr(source, "warnings", []))
    if dropped:
        warnings.append(f"{dropped} rows with NaN or inf were dropped")
    classes = None
    if labelled:
        classes = {name: int(histogram[i]) for i, name in enumerate(label_set.point_class_names)}
        classes["unlabelled"] = int(histogram[UNLABELLED])
    return SequenceInfo(
        path=Path(path),
        format=source.format,
        sensor=opened.sensor.name,
        beams=opened.sensor.n_rings,
        columns=opened.sensor.width,
        sensor_from=opened.sensor_from,
        frames=n,
        points_min=int(counts.min()),
        points_median=float(np.median(counts)),
        points_max=int(counts.max()),
        poses=pose_status(source),
        dropped_rows=dropped,
        class_histogram=classes,
        warnings=warnings,
    )
