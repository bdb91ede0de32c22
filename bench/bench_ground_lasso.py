"""What the ground lasso (issue 35) costs the viewer and the service, on a synthetic frame the size
of a real KITTI one (124,668 points, half of them ground, seed 0):

- `payload_ms`: the frame payload built from its artifact (app/viewer_payload.py) without and with
  the `ground` member the lasso needs, and the payload's bytes both ways;
- `click_ms`: a click ray turned into a vertex on the frame's ground (`click_on_ground`);
- `paint_ms`: the background cloud's 16,384 points coloured under 10 stored regions of 20
  vertices each, scattered over 80 x 80 m (`paint_regions`, on every draw while regions exist).

Medians of `REPEATS` runs (fewer with `--quick`). No target: the numbers go into docs/annotator.md.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

N_POINTS = 124_668
CLOUD = 16_384
REPEATS = 30


def _median_ms(fn: Callable[[], object], repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return round(1e3 * float(np.median(times)), 3)


def _payload(rng: np.random.Generator, repeats: int) -> dict:
    import app.viewer_payload as vp
    from app.artifacts import ArtifactStore, FrameArtifact

    seg = np.sort(rng.integers(-1, 400, N_POINTS)).astype(np.int32)
    ground = np.zeros(N_POINTS, bool)
    ground[: N_POINTS // 2] = True  # in runs, as scan order gives them
    fa = FrameArtifact(points=rng.normal(size=(N_POINTS, 3)).astype(np.float32),
                       intensity=rng.random(N_POINTS, dtype=np.float32), segment=seg, ground=ground,
                       track=np.where(seg >= 0, seg.astype(np.int64) + 100, 0),
                       samples=np.zeros((50, 4, 32, 32), np.uint8), sample_segment=np.arange(50, dtype=np.int32))
    out: dict = {}
    with tempfile.TemporaryDirectory(prefix="tl_lasso_") as tmp:
        store = ArtifactStore(tmp)
        path = store.path(store.write_frame(1, 0, fa))
        full = vp.PAYLOAD_ARRAYS
        for label, names in (("without_ground", tuple(n for n in full if n != "ground")), ("with_ground", full)):
            vp.PAYLOAD_ARRAYS = names
            try:
                body = vp.payload_from_artifact(path)
                assert body is not None
                out[label] = {"ms": _median_ms(lambda: vp.payload_from_artifact(path), repeats), "bytes": len(body)}
            finally:
                vp.PAYLOAD_ARRAYS = full
    return out


def run(out_dir: Path, quick: bool) -> dict:
    from annotator_ui.ground_regions import RegionClasses, StoredRegion, click_on_ground, paint_regions
    from pipeline.classes import CLASS_COLOURS

    repeats = 5 if quick else REPEATS
    rng = np.random.default_rng(0)
    payload = _payload(rng, repeats)
    pts = np.column_stack([rng.uniform(-50, 50, (N_POINTS, 2)), rng.normal(-1.7, 0.05, N_POINTS)]).astype(np.float32)
    ground = rng.random(N_POINTS) < 0.5
    click = _median_ms(lambda: click_on_ground(pts, ground, np.array([-10.0, 0.0, 10.0]), np.array([1.0, 0.1, -0.5])),
                       repeats)
    classes = RegionClasses.from_label_set([{"name": n, "colour": c, "ground": False} for n, c in CLASS_COLOURS.items()])
    ang = np.linspace(0, 2 * np.pi, 20, endpoint=False)
    regions = [StoredRegion(i, "bush", np.column_stack([cx + 8 * np.cos(ang), cy + 8 * np.sin(ang)]))
               for i, (cx, cy) in enumerate(rng.uniform(-40, 40, (10, 2)))]
    xy, eligible = rng.uniform(-40, 40, (CLOUD, 2)), rng.random(CLOUD) < 0.6
    colours = np.zeros((CLOUD, 3), np.uint8)
    paint = _median_ms(lambda: paint_regions(colours, xy, eligible, regions, classes), repeats)
    w, wo = payload["with_ground"], payload["without_ground"]
    return {
        "headline": f"payload {wo['ms']} -> {w['ms']} ms ({wo['bytes']:,} -> {w['bytes']:,} B); click {click} ms; "
                    f"paint {paint} ms",
        "payload": payload, "click_ms": click, "paint_ms": paint, "repeats": repeats,
        "points": N_POINTS, "cloud_points": CLOUD, "regions": len(regions),
    }
