"""A kept operator-benchmark state exported again with this checkout's code, and scored.

    python -m bench.effort.reexport KEEP SEQ [--label-set paper]

KEEP: a `bench_effort --keep` folder (its `service/` holds the database and the artifacts); SEQ:
the clip it labelled (`KEEP/clip/NAME` when the run cut frames). Starts the service on KEEP,
exports the sequence with the ground class as the benchmark does, and prints the labelled
non-ground and ground points and how many are right. Run from two checkouts on one state, it
measures a change of the export's rules (`pipeline.propagation`) without running the operator
again. The service adds an admin user to KEEP's database for the export; nothing else changes.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import httpx

from bench.effort.score import score_export
from bench.effort.service import Api, LocalService
from bench.effort.truth import SequenceTruth
from pipeline.label_sets import DEFAULT_LABEL_SET, preset


def reexport(keep: Path, seq: Path, label_set: str = DEFAULT_LABEL_SET) -> dict:
    """score_export of KEEP's one sequence exported now (include_ground, the default rules)."""
    truth = SequenceTruth(seq, preset(label_set))
    roots = [keep.resolve(), seq.resolve().parent]
    with LocalService(keep / "service", roots) as svc, httpx.Client(base_url=svc.url, timeout=900) as client:
        api = Api(client, svc.user(f"reexport-{time.time_ns()}", "admin"))
        sequences = api.get("/sequences")
        if len(sequences) != 1:
            raise SystemExit(f"{keep}: expected one sequence, found {len(sequences)}")
        return score_export(api.export(int(sequences[0]["id"]), include_ground=True), truth)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("keep", type=Path)
    ap.add_argument("seq", type=Path)
    ap.add_argument("--label-set", default=DEFAULT_LABEL_SET)
    args = ap.parse_args(argv)
    if not (args.keep / "service").is_dir():
        print(f"{args.keep}: no service/ folder (run bench_effort with --keep)", file=sys.stderr)
        return 2
    s = reexport(args.keep, args.seq, args.label_set)
    ng, g = s["non_ground_right_points"], s["ground_right_points"]
    print(f"non-ground {ng} / {s['non_ground_points']} ({s['non_ground_right']}), ground {g} / {s['ground_points']} "
          f"({s['ground_right']}), all {ng + g} / {s['non_ground_points'] + s['ground_points']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
