"""The operator benchmark: how much of a real recording is labelled right after N operator
actions, and how much can be labelled at all.

    python -m bench.bench_effort SEQ --out OUT [--actions N] [--frames A-B] [--label-set paper]
    python -m bench.run_all --only effort [--quick]     # the shared labelled clips

1. Start the service (`tracklabel serve`, SQLite, a temporary folder); through REST, register and
   ingest SEQ (a KITTI folder with `labels/`; `--frames` links a clip of it into the folder).
2. A simulated operator (bench/effort/operator.py) reviews what the queue offers, knowing the
   truth only of the points it is shown; the model in the loop retrains as reviews come in; the
   operator bulk-accepts the predictions the preview vouches for and a reviewer audits them.
3. At checkpoints (every 10 actions up to 100, then every 50) export SemanticKITTI labels through
   REST (ground on request) and score them against `labels/` (bench/effort/score.py).
Writes OUT/curve.json (the checkpoints, counts, timings, the bulk error measured against the
truth as each bulk was taken and after the audits, beside the audit's estimate), OUT/effort.png and OUT/export/ (the final export: one uint32
per input point, the input's file names, and its summary.json).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from contextlib import nullcontext
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import httpx

from bench.effort.operator import MODEL_SETTLE_S, WORKER_POLL_S, Counts, Operator, Policy
from bench.effort.score import (
    as_accepted_summary,
    bulk_as_accepted,
    bulk_error,
    bulk_tracks,
    prediction_calibration,
    score_export,
)
from bench.effort.service import Api, LocalService
from bench.effort.truth import SequenceTruth, TruthStore
from bench.real_data import REAL
from pipeline.label_sets import DEFAULT_LABEL_SET, preset, preset_names
from pipeline.propagation import Rules

CLIPS = {"kitti_seq00": (0, 9), "kitti_seq01": None, "kitti_seq02": None}
RADII = (0.3, 0.5, 1.0)  # the final state is also exported with these (radius, ground radius, far radius)
GROUND_RADII = (0.1, 0.2, 0.3)
FAR_RADII = (0.0, 2.0, 5.0, 10.0, 20.0)  # at the default radius and ground radius
REGION_RADII = (0.0, 0.3, 0.5, 1.0)  # a lasso's reach, at the other defaults


def checkpoints(budget: int) -> list[int]:
    """Action counts at which the export is scored: every 10 up to 100, then every 50."""
    marks = list(range(0, min(budget, 100) + 1, 10))
    return marks + list(range(150, budget + 1, 50))


def make_clip(seq: Path, first: int, last: int, dest: Path) -> Path:
    """A KITTI folder of frames first..last of `seq`: scans and labels linked, poses and times cut."""
    names = [f"{i:06d}" for i in range(first, last + 1)]
    for sub, ext in (("velodyne", "bin"), ("labels", "label")):
        (dest / sub).mkdir(parents=True, exist_ok=True)
        for n in names:
            src = (seq / sub / f"{n}.{ext}").resolve()
            if src.exists():
                (dest / sub / f"{n}.{ext}").symlink_to(src)
    for name in ("poses.txt", "times.txt"):
        if (seq / name).exists():
            lines = (seq / name).read_text().splitlines()
            (dest / name).write_text("\n".join(lines[first : last + 1]) + "\n")
    if (seq / "calib.txt").exists():
        (dest / "calib.txt").symlink_to((seq / "calib.txt").resolve())
    return dest


class Run:
    """One benchmark run over a registered, ingested sequence."""

    def __init__(self, svc_url: str, tokens: dict[str, str], seq_path: Path, truth: SequenceTruth, policy: Policy) -> None:
        self.client = httpx.Client(base_url=svc_url, timeout=600)
        self.admin, op, reviewer = (Api(self.client, tokens[k]) for k in ("admin", "operator", "reviewer"))
        t0 = time.monotonic()
        self.sequence_id = self.admin.register(seq_path, truth.label_set.name)
        self.admin.wait_ready(self.sequence_id)
        self.ingest_s = time.monotonic() - t0
        self.admin.wait_jobs_idle("assist")
        self.truth = truth
        frames = op.frames(self.sequence_id)
        store = TruthStore(dict(truth.all))
        rows = {name: ft.input_rows for name, ft in truth.labelled.items()}
        self.operator = Operator(op, reviewer, self.admin, self.sequence_id, frames, store, policy, truth.label_set, rows)
        self.curve: list[dict[str, Any]] = []
        self.bulks: list[dict[str, Any]] = []  # each bulk accept scored as taken (`_score_bulk`)
        self._bulk_ids: set[int] = set()
        self.operator.on_bulk = self._score_bulk

    def _score_bulk(self, bulk: dict[str, Any]) -> None:
        """Score a bulk accept against the truth before its audit: its tracks are those accepted in
        bulk now and not before the bulk round (audits and undos since only remove tracks)."""
        now = bulk_tracks(self.admin, self.sequence_id)
        taken = [t for i, t in now.items() if i not in self._bulk_ids]
        self.bulks.append(bulk_as_accepted(self.admin, bulk, taken, self.operator.frames, self.truth))
        self._bulk_ids = set(now)

    def checkpoint(self) -> dict[str, Any]:
        self.admin.wait_jobs_idle("assist", settle=MODEL_SETTLE_S)
        export = self.admin.export(self.sequence_id, include_ground=True)
        self.last_export = export
        c: Counts = self.operator.counts
        point = {"actions": c.actions, **asdict(c), **score_export(export, self.truth),
                 "sources": export.summary.get("labelled_by_source", {})}
        self.curve.append(point)
        return point

    def work(self, budget: int) -> None:
        marks = checkpoints(budget)
        self.checkpoint()
        marks.pop(0)
        op, pol = self.operator, self.operator.policy
        op.on_action = lambda: self._mark(marks)
        while op.counts.actions < budget and marks:
            if not op.review_next():
                break
            if op.counts.reviews % pol.bulk_every == 0:
                self._bulk_ids = set(bulk_tracks(self.admin, self.sequence_id))
                op.bulk_round()
            if op.counts.reviews % pol.ground_every == 0:
                op.region_pass(budget)
        if self.curve[-1]["actions"] != op.counts.actions:
            self.checkpoint()

    def _mark(self, marks: list[int]) -> None:
        """A checkpoint when the actions reached the next mark (after every action: the split and
        the labels of a review, a bulk accept and its audits are scored as they come)."""
        actions = self.operator.counts.actions
        if not marks or actions < marks[0]:
            return
        point = self.checkpoint()
        print(f"  {point['actions']:4d} actions: non-ground right {point['non_ground_right']:.3f}, "
              f"ground right {point['ground_right']}", file=sys.stderr)
        while marks and marks[0] <= actions:
            marks.pop(0)

    def variants(self) -> list[dict[str, Any]]:
        """The final state exported with other propagation radii: how far labels should travel."""
        d = Rules()
        grid = [replace(d, radius=r, ground_radius=g) for r in RADII for g in GROUND_RADII]
        grid += [replace(d, far_radius=f) for f in FAR_RADII if f != d.far_radius]
        grid += [replace(d, region_radius=r) for r in REGION_RADII if r != d.region_radius]
        rows = []
        for rules in grid:
            radii = {"radius": rules.radius, "ground_radius": rules.ground_radius, "far_radius": rules.far_radius,
                     "region_radius": rules.region_radius}
            s = score_export(self.admin.export(self.sequence_id, include_ground=True, **radii), self.truth)
            rows.append({**radii, "non_ground_right": s["non_ground_right"], "ground_right": s["ground_right"]})
        return rows

    def _undone_bulks(self) -> set[int]:
        return {int(b["id"]) for b in self.admin.get(f"/sequences/{self.sequence_id}/bulk-actions") if b.get("undone_at")}

    def assist_seconds(self) -> list[float]:
        jobs = self.admin.get("/jobs", params={"type": "assist", "status": "succeeded", "limit": 1000})
        return [float(j["result"]["seconds"]) for j in jobs if j.get("result")]

    def finish(self, out: Path) -> dict[str, Any]:
        _write_export(self.last_export.tar, out / "export")
        stats = self.admin.get("/exports/stats", params={"sequence_id": self.sequence_id})
        ops = self.operator
        return {"sequence_id": self.sequence_id, "ingest_seconds": round(self.ingest_s, 1),
                "policy": asdict(ops.policy), "curve": self.curve,
                "bulk_error_measured": bulk_error(self.admin, self.sequence_id, ops.frames, self.truth),
                "pending_predictions": prediction_calibration(self.admin, self.sequence_id, ops.frames, self.truth),
                "bulk_error_audited": stats["audit"]["bulk"], "operations_in_the_log": stats["operations"],
                "bulk_error_as_accepted": as_accepted_summary(self.bulks, self._undone_bulks()),
                "assist_runs_seconds": self.assist_seconds(), "export_variants": self.variants()}


def _write_export(tar_bytes: bytes, dest: Path) -> None:
    """The export's labels/ and summary.json under `dest`, named as the input's frames."""
    import io
    import tarfile

    dest.mkdir(parents=True, exist_ok=True)
    with tarfile.open(fileobj=io.BytesIO(tar_bytes)) as tar:
        for m in tar.getmembers():
            name = Path(m.name)
            target = dest / (name.parent.name if name.suffix in (".label", ".source") else "") / name.name
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_bytes(tar.extractfile(m).read())  # type: ignore[union-attr]


def plot(results: dict[str, dict[str, Any]], path: Path) -> None:
    """Non-ground and ground points right against actions, one line per clip."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    for name, res in results.items():
        xs = [p["actions"] for p in res["curve"]]
        axes[0].plot(xs, [p["non_ground_right"] for p in res["curve"]], marker=".", label=name)
        axes[1].plot(xs, [p["ground_right"] for p in res["curve"]], marker=".", label=name)
    for ax, title in zip(axes, ("non-ground points right", "ground points right"), strict=True):
        ax.set_xlabel("operator actions")
        ax.set_title(title)
        ax.grid(alpha=0.3)
        ax.set_ylim(0, 1)
    axes[0].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run_sequence(seq: Path, out: Path, budget: int, frames: tuple[int, int] | None = None,
                 policy: Policy | None = None, assist_every: int | None = None, keep: Path | None = None,
                 label_set: str = DEFAULT_LABEL_SET) -> dict[str, Any]:
    """The benchmark on one sequence (module docstring); writes OUT/curve.json, effort.png, export/.
    keep: the service's folder (database, artifacts, the clip's links) is made there and kept, so
    that `tracklabel serve` and the annotator can show what the operator did; else a temporary one."""
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    if keep is not None:
        keep.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="tl_effort_") if keep is None else nullcontext(str(keep.resolve())) as tmp:
        clip = make_clip(seq, *frames, Path(tmp) / "clip" / seq.name) if frames else seq.resolve()
        truth = SequenceTruth(clip, preset(label_set))
        env = {"TRACKLABEL_WORKER_POLL_SECONDS": str(WORKER_POLL_S)}
        if assist_every is not None:
            env["TRACKLABEL_ASSIST_EVERY"] = str(assist_every)
        with LocalService(Path(tmp) / "service", [Path(tmp), seq.resolve().parent], env) as svc:
            tokens = {role: svc.user(role, role) for role in ("admin", "operator", "reviewer")}
            run = Run(svc.url, tokens, clip, truth, policy or Policy())
            run.work(budget)
            result = {"sequence": str(seq), "frames": list(frames) if frames else None, "label_set": label_set,
                      "assist_every": assist_every,
                      **run.finish(out), "seconds": round(time.monotonic() - t0, 1)}
    (out / "curve.json").write_text(json.dumps(result, indent=1))
    plot({seq.name: result}, out / "effort.png")
    return result


def _at(curve: list[dict[str, Any]], actions: int) -> dict[str, Any]:
    """The last checkpoint at or before `actions`."""
    return [p for p in curve if p["actions"] <= actions][-1]


def run(out_dir: Path, quick: bool) -> dict:
    """run_all entry: the shared labelled clips, 50 actions (quick) or 150. How much can be labelled
    at all (every track reviewed) is a longer run of its own (docs/effort.md)."""
    if not REAL.is_dir():
        return {"skipped": "../shared/data/real is absent"}
    budget = 50 if quick else 150
    results = {name: run_sequence(REAL / name, out_dir / "effort" / name, budget, frames)
               for name, frames in CLIPS.items()}
    plot(results, out_dir / "effort.png")
    at50 = {n: _at(r["curve"], 50)["non_ground_right"] for n, r in results.items()}
    final = {n: r["curve"][-1]["non_ground_right"] for n, r in results.items()}
    mean50 = round(sum(at50.values()) / len(at50), 4)
    return {
        "headline": f"non-ground right after <= 50 actions: {at50} (mean {mean50}); at the end: {final}",
        "non_ground_right_at_50": at50, "non_ground_right_final": final,
        "targets": {"non_ground_right_at_50_mean": {"value": mean50, "target": 0.95, "met": mean50 >= 0.95}},
        "clips": {n: {k: v for k, v in r.items() if k != "curve"} | {"curve": r["curve"]} for n, r in results.items()},
    }


def _frames(text: str) -> tuple[int, int]:
    a, _, b = text.partition("-")
    return int(a), int(b or a)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("seq", type=Path, help="a KITTI folder with labels/")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--actions", type=int, default=2000, help="the action budget (the run also ends with the queue)")
    ap.add_argument("--frames", type=_frames, default=None, help="A-B: only frames A..B of the sequence")
    ap.add_argument("--label-set", default=DEFAULT_LABEL_SET, help="the label set (a preset) to register and score in")
    ap.add_argument("--queue", choices=("priority", "size"), default="priority", help="the review queue's order")
    ap.add_argument("--keep", type=Path, default=None,
                    help="a folder to make the service in and keep (default: a temporary one)")
    ap.add_argument("--assist-every", type=int, default=None,
                    help="the service's assist_every (reviews between retrains; default: the service's own)")
    args = ap.parse_args(argv)
    if args.label_set not in preset_names():
        print(f"--label-set: unknown label set {args.label_set!r}; known: {', '.join(preset_names())}", file=sys.stderr)
        return 2
    if not (args.seq / "labels").is_dir():
        print(f"{args.seq}: no labels/ folder to score against", file=sys.stderr)
        return 2
    if args.keep is not None and args.keep.exists() and any(args.keep.iterdir()):
        print(f"--keep: {args.keep} is not empty", file=sys.stderr)
        return 2
    res = run_sequence(args.seq, args.out, args.actions, args.frames, Policy(queue=args.queue), args.assist_every,
                       args.keep, args.label_set)
    last = res["curve"][-1]
    print(f"{last['actions']} actions: non-ground right {last['non_ground_right']}, ground right {last['ground_right']}")
    taken = res["bulk_error_as_accepted"]
    print(f"bulk accepts as taken: {taken['all']}; of the bulks kept: {taken['kept']}; "
          f"after the audits: {res['bulk_error_measured']['track_error']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
