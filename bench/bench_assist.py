"""The model in the review loop on a 60-frame real sequence: how long after a batch of reviews the
retrained predictions are in the database.

    python -m bench.run_all --only assist

kitti_seq00 (SemanticKITTI 00, 60 frames, HDL-64E) is registered and ingested through REST into
`tracklabel serve` on SQLite (bench/effort/service.py). A simulated operator (bench/effort) then
reviews batches of `assist_every` (5) tracks; after each batch the clock runs from its last
review until the assist run that includes it has written every track's prediction (the run is
queued by the worker by itself, so the wait for the worker's poll counts). Before the reviews,
`PRISMS` regions with heights are drawn along the route (20 m squares of 32 vertices from 1.5 m
below the sensor to 1 m above it), as the operator benchmark's operator draws its prisms first:
each run then also counts, frame by frame, the points they label. Reported per batch:
that latency and the run's own seconds; the target is 60 s on the 2-core machine. Skipped
when ../shared/data/real is absent.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import httpx
import numpy as np

from bench.effort.operator import WORKER_POLL_S, Operator, Policy
from bench.effort.service import Api, LocalService
from bench.effort.truth import SequenceTruth, TruthStore
from bench.real_data import REAL

TARGET_S = 60.0
BATCH = 5
PRISMS = 20


def _draw_prisms(admin: Api, sequence_id: int, frames: list, n: int) -> None:
    """`n` prisms centred on every few frames' sensor positions (see the module docstring)."""
    angles = np.linspace(0, 2 * np.pi, 32, endpoint=False)
    square = np.column_stack([np.cos(angles), np.sin(angles)])
    square = 10.0 * square / np.abs(square).max(axis=1, keepdims=True)  # a 20 m square's outline
    for f in frames[:: max(len(frames) // n, 1)][:n]:
        x, y, z = (float(v) for v in f.T_world_lidar[:3, 3])
        admin.post(f"/sequences/{sequence_id}/ground-regions",
                   {"class_name": "bush", "polygon": (square + [x, y]).tolist(), "z_min": z - 1.5, "z_max": z + 1.0})


def _run_after(admin: Api, event_id: int, timeout: float = 600.0) -> dict:
    """The succeeded assist job that took in review event `event_id` (waits for it)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for j in admin.get("/jobs", params={"type": "assist", "status": "succeeded", "limit": 20}):
            if int(j["params"]["after_event"]) >= event_id:
                return j
        time.sleep(0.1)
    raise RuntimeError(f"no assist run took in event {event_id} within {timeout:g} s")


def _newest_event(admin: Api, sequence_id: int) -> int:
    page = admin.get("/tracks", params={"sequence_id": sequence_id, "sort": "-updated_at", "limit": 1})
    return max(e["id"] for e in admin.get(f"/tracks/{page['items'][0]['id']}/events"))


def run(out_dir: Path, quick: bool) -> dict:
    seq = REAL / "kitti_seq00"
    if not seq.is_dir():
        return {"skipped": "../shared/data/real is absent"}
    batches = 2 if quick else 4
    with tempfile.TemporaryDirectory(prefix="tl_assist_") as tmp:
        env = {"TRACKLABEL_WORKER_POLL_SECONDS": str(WORKER_POLL_S), "TRACKLABEL_ASSIST_EVERY": str(BATCH)}
        with LocalService(Path(tmp) / "service", [seq.resolve().parent], env) as svc:
            tokens = {role: svc.user(role, role) for role in ("admin", "operator", "reviewer")}
            client = httpx.Client(base_url=svc.url, timeout=600)
            admin, op, reviewer = (Api(client, tokens[k]) for k in ("admin", "operator", "reviewer"))
            t0 = time.monotonic()
            sequence_id = admin.register(seq.resolve())
            admin.wait_ready(sequence_id, timeout=3600)
            ingest_s = time.monotonic() - t0
            first = _run_after(admin, 0)
            frames = op.frames(sequence_id)
            _draw_prisms(admin, sequence_id, frames, PRISMS)
            store = TruthStore(dict(SequenceTruth(seq).all))
            # one event per review (no splits), so each batch of BATCH reviews is one due run
            policy = Policy(split_gain=10**9, wait_for_model=False)
            operator = Operator(op, reviewer, admin, sequence_id, frames, store, policy)
            rows = []
            for _ in range(batches):
                for _ in range(BATCH):
                    operator.review_next()
                t_sent = time.monotonic()
                job = _run_after(admin, _newest_event(admin, sequence_id))
                rows.append({"reviews": operator.counts.reviews, "latency_s": round(time.monotonic() - t_sent, 2),
                             "run_s": job["result"]["seconds"], "samples": job["result"]["samples"],
                             "reviewed_samples": job["result"]["reviewed_samples"]})
            client.close()
    worst = max(r["latency_s"] for r in rows)
    return {
        "headline": f"reviews -> retrained predictions on 60 frames: worst {worst:.1f} s "
                    f"(median {np.median([r['latency_s'] for r in rows]):.1f} s; target {TARGET_S:g} s)",
        "frames": len(frames), "prisms": PRISMS, "ingest_seconds": round(ingest_s, 1), "first_run_s": first["result"]["seconds"],
        "batches": rows,
        "targets": {"retrain_latency_s": {"value": worst, "target": TARGET_S, "met": worst <= TARGET_S}},
    }
