"""What more prisms would put right on a state the operator benchmark exported, without the service.

    python -m bench.effort.replay_regions SEQ OUT [--frames A-B] [--regions 15] [--undecided-only]
                                          [--cells 0.5,0.35] [--vertices 32] [--view-lassos 0]

SEQ: the clip's KITTI folder (with labels/ and poses); OUT: a `bench_effort` output folder (its
`export/` holds the final export with its sources). The planner of the simulated operator
(`bench.effort.ground.plan_prism`) draws prisms one after another over every point of the
labelled frames, each applied with the service's rule (`pipeline.propagation.GroundRegion`),
while one puts at least `--min-gain` points right; `--undecided-only` lets them label only the
points no reviewed or bulk-accepted track holds. `--cells` (the grids areas are read from, in
metres) and `--vertices` (the longest outline) default to the operator's; the API takes outlines
of up to 1,000 vertices. Then, with `--view-lassos N`, up to N lassos per frame drawn in the
frame's view (`bench.effort.view_lasso`), each while it puts at least `--min-gain` points right.
Prints the non-ground and ground points right after each region.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from bench.bench_effort import _frames
from bench.effort.ground import PRISM_CELLS, PRISM_VERTICES, plan_prism
from bench.effort.score import exported_classes, is_ground
from bench.effort.service import Export
from bench.effort.truth import SequenceTruth
from bench.effort.view_lasso import plan_view_lasso
from pipeline.classes import UNLABELLED
from pipeline.io.registry import open_reader
from pipeline.label_sets import LabelSet, preset
from pipeline.propagation import GroundRegion, to_world


def load(seq: Path, out: Path, frames: tuple[int, int] | None, label_set: str) -> dict[str, np.ndarray]:
    """Every labelled frame's stored points: world, true class, exported class, whether decided,
    frame index; and the frames' poses ("poses", (F, 4, 4), by frame index)."""
    ls = preset(label_set)
    truth, source, export = SequenceTruth(seq, ls), open_reader(seq), Export.read(out / "export")
    names = export.summary["sources"]
    decided = [names.index("reviewed"), names.index("bulk")]
    parts: dict[str, list[np.ndarray]] = {"world": [], "true": [], "current": [], "decided": [], "frame": []}
    first, last = frames or (0, len(source) - 1)
    for i in range(first, last + 1):
        name = source.frame_name(i)
        if name not in truth.labelled:
            continue
        ft, rows = truth.labelled[name], truth.labelled[name].input_rows
        words, src = export.labels[name], export.sources[name]
        if rows is not None:
            words, src = words[rows], src[rows]
        parts["world"].append(to_world(source.frame(i).points[:, :3], source.poses[i]))
        parts["true"].append(ft.classes)
        parts["current"].append(exported_classes(words, ls))
        parts["decided"].append(np.isin(src, decided))
        parts["frame"].append(np.full(len(ft.classes), i, np.int64))
    return {**{k: np.concatenate(v) for k, v in parts.items()}, "poses": np.asarray(source.poses, np.float64)}


def replay(state: dict[str, np.ndarray], ls: LabelSet, regions: int, min_gain: int, undecided_only: bool,
           cells: tuple[float, ...] = PRISM_CELLS, vertices: int = PRISM_VERTICES) -> list[dict[str, float]]:
    """Draw up to `regions` prisms greedily; the scores after each (the first row: none)."""
    world, true, current = state["world"], state["true"], state["current"].copy()
    objects, n_classes = len(ls.sample_classes), len(ls.point_classes)
    free = ~state["decided"] if undecided_only else np.ones(len(true), bool)
    g = is_ground(true, ls)
    ng = ~g & (true != UNLABELLED)
    rows = [_score(current, true, ng, g, 0)]
    for _ in range(regions):
        seen = np.flatnonzero(free)
        lasso = plan_prism(world[seen], true[seen], current[seen], objects, n_classes, cells, vertices)
        if lasso is None or lasso.gain < min_gain:
            break
        inside = GroundRegion(lasso.polygon, lasso.class_, lasso.heights).labels(world, None) & free
        current[inside] = lasso.class_
        rows.append(_score(current, true, ng, g, lasso.gain))
    state["current"] = current
    return rows


def replay_views(state: dict[str, np.ndarray], ls: LabelSet, per_frame: int, min_gain: int,
                 undecided_only: bool) -> Iterator[dict[str, float]]:
    """Draw up to `per_frame` lassos in each frame's view greedily (`replay`'s state, changed in
    place); the scores after each, as they are drawn."""
    world, true, current, frame = state["world"], state["true"], state["current"], state["frame"]
    free = ~state["decided"] if undecided_only else np.ones(len(true), bool)
    g = is_ground(true, ls)
    ng = ~g & (true != UNLABELLED)
    for f in np.unique(frame):
        mine = np.flatnonzero((frame == f) & free)
        for _ in range(per_frame):
            lasso = plan_view_lasso(world[mine], true[mine], current[mine], state["poses"][f], int(f),
                                    len(ls.point_classes))
            if lasso is None or lasso.gain < min_gain:
                break
            current[mine[lasso.rule(int(f)).labels(world[mine], None, int(f))]] = lasso.class_
            yield {"frame": int(f), **_score(current, true, ng, g, lasso.gain)}


def _score(current: np.ndarray, true: np.ndarray, ng: np.ndarray, g: np.ndarray, gain: int) -> dict[str, float]:
    return {"gain": gain, "non_ground_right": round(float((current[ng] == true[ng]).mean()), 4),
            "ground_right": round(float((current[g] == true[g]).mean()), 4)}


def _cells(text: str) -> tuple[float, ...]:
    sizes = tuple(float(v) for v in text.split(","))
    if min(sizes) <= 0:
        raise argparse.ArgumentTypeError("cell sizes must be positive metres, e.g. 0.5,0.35")
    return sizes


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("seq", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--frames", type=_frames, default=None, help="A-B: the clip's frames (as bench_effort's --frames)")
    ap.add_argument("--regions", type=int, default=15)
    ap.add_argument("--min-gain", type=int, default=200)
    ap.add_argument("--undecided-only", action="store_true")
    ap.add_argument("--label-set", default="paper")
    ap.add_argument("--cells", type=_cells, default=PRISM_CELLS, help="grid sizes in metres, e.g. 0.5,0.35,0.2")
    ap.add_argument("--vertices", type=int, default=PRISM_VERTICES, help="the longest outline (the API's limit: 1000)")
    ap.add_argument("--view-lassos", type=int, default=0, help="then at most this many lassos in each frame's view")
    a = ap.parse_args()
    state = load(a.seq, a.out, a.frames, a.label_set)
    rows = replay(state, preset(a.label_set), a.regions, a.min_gain, a.undecided_only, a.cells, a.vertices)
    for k, row in enumerate(rows):
        print(json.dumps({"prisms": k, **row}), flush=True)
    if a.view_lassos > 0:
        views = replay_views(state, preset(a.label_set), a.view_lassos, a.min_gain, a.undecided_only)
        for k, row in enumerate(views, start=1):
            print(json.dumps({"view_lassos": k, **row}), flush=True)


if __name__ == "__main__":
    main()
