"""Where an exported state's wrong points went, by true class, exported class and source.

    python -m bench.effort.losses SEQ OUT [--label-set paper] [--top 15] [--ground]

SEQ: the clip's KITTI folder (with labels/); OUT: a `bench_effort` output folder (its `export/`
holds the final export with its sources). Prints the wrong share of the labelled non-ground
points (with --ground: of the ground points), then the largest groups, each as a share of those
points. "ground" as a source means the export wrote the point as ground: the ground estimate
took it and no region relabelled it.
"""

from __future__ import annotations

import argparse
from collections import Counter
from pathlib import Path

import numpy as np

from bench.effort.score import exported_classes, is_ground
from bench.effort.service import Export
from bench.effort.truth import SequenceTruth
from pipeline.classes import UNLABELLED
from pipeline.label_sets import DEFAULT_LABEL_SET, LabelSet, preset


def tally(true: np.ndarray, exported: np.ndarray, source: np.ndarray, ls: LabelSet,
          ground: bool = False) -> tuple[Counter, int]:
    """Wrong labelled non-ground points (ground: ground points) per (true class, exported class,
    source index); and the points counted. `exported` is UNLABELLED where the export wrote 0."""
    ng = (is_ground(true, ls) if ground else ~is_ground(true, ls)) & (true != UNLABELLED)
    bad = ng & (exported != true)
    keys, counts = np.unique(np.stack([true[bad], exported[bad], source[bad]], 1).astype(np.int64), axis=0,
                             return_counts=True)
    return Counter({tuple(int(v) for v in k): int(c) for k, c in zip(keys, counts, strict=True)}), int(ng.sum())


def losses(seq: Path, out: Path, ls: LabelSet, ground: bool = False) -> tuple[Counter, int, list[str]]:
    """tally over every labelled frame of the export in OUT; and the export's source names."""
    export = Export.read(out / "export")
    wrong, total = Counter(), 0
    for name, ft in SequenceTruth(seq, ls).labelled.items():
        if name not in export.labels:
            raise FileNotFoundError(f"{out / 'export'}: the export has no labels for frame {name}")
        w, n = tally(ft.per_input_row(), exported_classes(export.labels[name], ls), export.sources[name], ls, ground)
        wrong, total = wrong + w, total + n
    return wrong, total, export.summary["sources"]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("seq", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--label-set", default=DEFAULT_LABEL_SET)
    ap.add_argument("--top", type=int, default=15)
    ap.add_argument("--ground", action="store_true", help="the ground points' losses instead")
    args = ap.parse_args(argv)
    ls = preset(args.label_set)
    wrong, total, sources = losses(args.seq, args.out, ls, args.ground)
    kind = "ground" if args.ground else "non-ground"
    print(f"{args.seq.name}: {sum(wrong.values()) / max(total, 1):.4f} of {total} {kind} points wrong")
    cls = [*ls.point_class_names]
    for (t, e, s), n in wrong.most_common(args.top):
        exported = "nothing" if e == UNLABELLED else cls[e]
        print(f"  {cls[t]:>14} as {exported:<14} {sources[s]:<11} {n / total:.4f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
