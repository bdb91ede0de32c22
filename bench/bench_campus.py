"""Campus benchmark: the perception pipeline's quality on the simulated campus, and how the
campus's surfaces compare with real scans.

1. Simulate seed 0 (200 frames; 40 with --quick), process it with the default config, or with
   the YAML of overrides named by the environment variable TRACKLABEL_BENCH_CONFIG (to compare
   settings), and score it with `pipeline.evaluation`: purity, pure fraction, link precision,
   recall and thing recall (the recall over person, car and cyclist presences), overall and per
   class, and the object summary (thing cover). Targets: purity >= 0.97, precision >= 0.99,
   recall >= 0.90.
2. `impure_structures`: which kinds of objects the impure segments (purity < 0.95) join, by the
   points they cost (hedge + building, car + car, ...).
3. With ../shared/data/real present: texture statistics (`research.simulation.texture`) of the
   labelled SemanticKITTI frames 0-2 of sequence 00 (HDL-64E) next to the campus cast with an
   HDL-64E (seeds 0 and 1, 10 frames each; 4 with --quick), and the campus's own HDL-32E;
   `texture.png` in the output folder (docs/simulator.md shows it).
"""

from __future__ import annotations

import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.real_data import kitti_seq00
from pipeline.config import PipelineConfig, load_config
from pipeline.evaluation import object_keys
from pipeline.pipeline import evaluate_folder, run_process

TARGETS = {"purity": 0.97, "association_precision": 0.99, "association_recall": 0.90}
ROW_KEYS = ("segments", "purity", "pure_fraction", "links", "association_precision", "presences",
            "association_recall")
CONFIG_ENV = "TRACKLABEL_BENCH_CONFIG"


def quality(ev: dict) -> dict:
    """The evaluation's overall and per-class rows, the thing link recall of its object summary
    (person, car and cyclist presences) added to the overall row, and that summary (`objects`:
    ground left out, thing cover)."""
    overall = {k: ev["overall"][k] for k in (*ROW_KEYS, "over_segmentation")}
    overall["thing_recall"] = ev["summary"]["thing_link_recall"]
    return {"overall": overall, "per_class": {c: {k: b[k] for k in ROW_KEYS} for c, b in ev["per_class"].items()},
            "objects": ev["summary"]}


def impure_structures(seq: Path, out: Path, top: int = 12) -> dict:
    """What the impure segments (purity < 0.95) join: per pair of instance kinds (the segment's
    dominant object's kind + another object's kind), the points of the other object in them, as
    a share of all points outside their segment's dominant object."""
    from pipeline.sequence import open_sequence

    kinds = {int(k): v["kind"] for k, v in json.loads((seq / "metadata.json").read_text())["instances"].items()}
    kinds[0] = "ground"
    source = open_sequence(seq).source
    cost: dict[str, int] = {}
    total = 0
    for i in range(len(source)):
        scan = source.frame(i)
        track = np.fromfile(out / "tracks" / f"{source.frame_name(i)}.label", dtype=np.uint32).astype(np.int64)
        key, _ = object_keys(scan.semantic, scan.instance)
        for pair, n in _frame_pairs(track, key, scan.instance.astype(np.int64), kinds).items():
            cost[pair] = cost.get(pair, 0) + n
            total += n
    ranked = sorted(cost.items(), key=lambda kv: -kv[1])[:top]
    return {"impure_points": total, "pairs": [{"kinds": k, "points": n, "share": round(n / max(total, 1), 4)}
                                              for k, n in ranked]}


def _frame_pairs(track: np.ndarray, key: np.ndarray, inst: np.ndarray, kinds: dict[int, str]) -> dict[str, int]:
    m = track > 0
    t, k, ins = track[m], key[m], inst[m]
    out: dict[str, int] = {}
    for tid in np.unique(t):
        sel = t == tid
        keys, counts = np.unique(k[sel], return_counts=True)
        if counts.max() >= 0.95 * counts.sum():
            continue
        dom = keys[np.argmax(counts)]

        def kind_of(kk: int, sel: np.ndarray = sel) -> str:
            ids, c = np.unique(ins[sel][k[sel] == kk], return_counts=True)
            return kinds.get(int(ids[np.argmax(c)]), "?")

        dom_kind = kind_of(int(dom))
        for kk, n in zip(keys, counts, strict=True):
            if kk != dom:
                pair = " + ".join(sorted((dom_kind, kind_of(int(kk)))))
                out[pair] = out.get(pair, 0) + int(n)
    return out


def texture(out_dir: Path, quick: bool) -> dict | None:
    """Texture statistics of real labelled HDL-64E frames and of the campus (HDL-64E and its own
    HDL-32E); None without the real data. Writes texture.png to `out_dir`."""
    from pipeline.plots import quantile_comparison
    from pipeline.scan import Scan
    from pipeline.sensors import PRESETS
    from pipeline.sequence import open_sequence
    from research.simulation import simulate_frame
    from research.simulation.scene import build_scene
    from research.simulation.texture import texture_statistics

    with tempfile.TemporaryDirectory() as tmp:
        real = kitti_seq00(Path(tmp) / "k00", frames=range(3))
        if real is None:
            return None
        opened = open_sequence(real)
        stats = {"real HDL-64E (KITTI 00, frames 0-2)": texture_statistics(
            (opened.source.frame(i) for i in range(len(opened))), opened.sensor)}
    frames = range(0, 200, 50 if quick else 20)
    scenes = [build_scene(seed) for seed in (0, 1)]
    for name in ("hdl64e", "hdl32e"):
        sensor = PRESETS[name]

        def scans(sensor=sensor):
            for scene in scenes:
                for k in frames:
                    ret = simulate_frame(scene, k, sensor=sensor)[1]
                    yield Scan(ret.points, ret.remission, ret.ring, semantic=ret.semantic, instance=ret.instance)

        stats[f"campus {name.upper().replace('HDL', 'HDL-')}"] = texture_statistics(scans(), sensor)
    quantile_comparison(stats, {"row_residual_cm": "row residual (cm, log)", "beam_residual_cm":
                                "beam residual (cm, log)", "intensity": "intensity"},
                        out_dir / "texture.png", log={"row_residual_cm", "beam_residual_cm"})
    return {"frames_per_seed": len(frames), "stats": stats}


def run(out_dir: Path, quick: bool = False) -> dict:
    from research.simulation import simulate_sequence

    frames = 40 if quick else 200
    config_path = os.environ.get(CONFIG_ENV)
    config = load_config(config_path) if config_path else PipelineConfig()
    result: dict = {"frames": frames, "seed": 0, "config": config_path or "defaults",
                    "load_average_1min_start": os.getloadavg()[0]}
    with tempfile.TemporaryDirectory() as tmp:
        seq, out = Path(tmp) / "campus", Path(tmp) / "out"
        t0 = time.perf_counter()
        sim = simulate_sequence(seq, frames=frames, seed=0)
        result["simulate_seconds"] = round(time.perf_counter() - t0, 2)
        result["simulate_frames_per_second"] = round(sim.fps, 2)
        t0 = time.perf_counter()
        run_process(seq, out, config)
        result["process_seconds"] = round(time.perf_counter() - t0, 2)
        result["quality"] = q = quality(evaluate_folder(seq, out))
        result["impure"] = impure_structures(seq, out)
    result["texture"] = texture(out_dir, quick)
    o = q["overall"]
    result["targets"] = {k: {"value": o[k], "target": v, "met": o[k] is not None and o[k] >= v}
                         for k, v in TARGETS.items()}
    result["headline"] = (f"purity {o['purity']:.3f}, precision {o['association_precision']:.3f}, recall "
                          f"{o['association_recall']:.3f}, thing recall {o['thing_recall']:.3f} ({result['config']})")
    return result


if __name__ == "__main__":
    import sys

    print(json.dumps(run(Path("bench/results"), quick="--quick" in sys.argv), indent=2))
