"""The ground truth of a labelled recording, per point of the service's frames.

`SequenceTruth` holds every frame's classes (the label set's class index per point, in the order
the service stores the frame's points: the scan's rows without NaN, inf or no-return rows). The
scorer reads it whole. The simulated operator gets a `TruthStore`, which answers only for points
the operator has been shown and records every read, as a person at the viewer knows the truth of
what is on the screen and nothing else.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipeline.classes import UNLABELLED
from pipeline.label_sets import DEFAULT_LABEL_SET, LabelSet, preset


@dataclass(frozen=True)
class FrameTruth:
    """classes: (N,) uint8 class per stored point (UNLABELLED = no truth); input_rows: (N_input,)
    bool the scan rows that are stored points (None = all); labels_file: where it came from."""

    classes: np.ndarray
    input_rows: np.ndarray | None
    labels_file: Path

    def per_input_row(self) -> np.ndarray:
        """(N_input,) uint8 the classes of every row of the scan file (UNLABELLED for rows that are no point)."""
        if self.input_rows is None:
            return self.classes
        out = np.full(len(self.input_rows), UNLABELLED, np.uint8)
        out[self.input_rows] = self.classes
        return out


class SequenceTruth:
    """The truth of a KITTI-layout folder with `labels/` in a label set's classes: `labelled` holds
    the frames with a labels file, `all` every frame's classes per stored point (UNLABELLED for
    frames without labels)."""

    def __init__(self, seq: Path, label_set: LabelSet | None = None) -> None:
        from pipeline.io.registry import open_reader

        self.label_set = label_set or preset(DEFAULT_LABEL_SET)
        table = self.label_set.to_index_table()
        source = open_reader(seq)
        self.labelled: dict[str, FrameTruth] = {}
        self.all: dict[str, np.ndarray] = {}
        for i in range(len(source)):
            name, scan = source.frame_name(i), source.frame(i)
            labels_file = Path(seq) / "labels" / f"{name}.label"
            if not labels_file.exists():
                self.all[name] = np.full(len(scan.points), UNLABELLED, np.uint8)
                continue
            raw = np.fromfile(labels_file, np.uint32)
            if len(raw) != scan.n_input:
                raise ValueError(f"{labels_file}: {len(raw)} labels for {scan.n_input} points")
            rows = scan.input_rows
            ft = FrameTruth(table[(raw if rows is None else raw[rows]) & 0xFFFF], rows, labels_file)
            self.labelled[name], self.all[name] = ft, ft.classes


@dataclass
class TruthStore:
    """What the operator may know: the truth of the points it was shown (`show`), no more."""

    truth: dict[str, np.ndarray]  # frame name -> (N,) classes of the stored points
    shown: dict[str, set[int]] = field(default_factory=dict)
    item: int | None = None  # the track under review
    reads: list[tuple[int | None, str, np.ndarray]] = field(default_factory=list)  # (item, frame, points)

    def show(self, frame: str, points: np.ndarray, item: int | None = None) -> None:
        """The viewer drew these points of `frame` as the item (track) under review."""
        self.shown.setdefault(frame, set()).update(int(i) for i in points)
        self.item = item

    def read(self, frame: str, points: np.ndarray) -> np.ndarray:
        """The true classes of `points` of `frame`; PermissionError for a point not shown."""
        points = np.asarray(points, np.int64)
        seen = self.shown.get(frame, set())
        unseen = [int(i) for i in points if int(i) not in seen]
        if unseen:
            raise PermissionError(f"frame {frame}: the operator was not shown points {unseen[:5]}")
        self.reads.append((self.item, frame, points.copy()))
        return self.truth[frame][points]

    def forget(self) -> None:
        """The item left the screen."""
        self.shown.clear()
        self.item = None
