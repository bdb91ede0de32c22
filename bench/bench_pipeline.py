"""Perception pipeline benchmark (issue 3 targets) on a 200-frame simulated HDL-32E sequence.

Targets: projection + ground + segmentation median <= 5 ms per frame; the whole process run
>= 20 frames/s with 64x64 samples and >= 10 frames/s with 256x256; segment purity >= 0.97;
association precision >= 0.99 and recall >= 0.90. Also timings, segment counts and tracks that
span every frame on the real recordings in ../shared/data/real (no labels there).

The projection + ground + segmentation target is the median wall time per frame inside the
single-worker 64x64 run. `pgs_isolated` times the three stages alone, wall time and the process's
CPU time (all threads: the stages' kernels run rows, columns and points on numba's thread pool,
so CPU time can exceed wall time on the 2-core machine). Quality is
also measured on three more simulated scenes (seeds 1-3, `*_seed1` ... `*_seed3`); seed 1 helped
choose the association thresholds, seeds 2 and 3 did not.
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.real_data import kitti_seq09, nuscenes_sweep
from pipeline.config import PipelineConfig
from pipeline.pipeline import evaluate_folder, run_process

KEYS = ("frames", "segments", "valid_segments", "samples", "tracks", "tracks_multi_frame",
        "tracks_spanning_all_frames", "constraint_pairs", "ms_project_ground_segment", "ms",
        "frames_per_second", "sensor", "range_image")


def _pick(summary: dict) -> dict:
    return {k: summary[k] for k in KEYS if k in summary}


def _pgs_isolated(seq: Path) -> dict:
    """Projection + ground + segmentation alone over every frame (scans read beforehand), wall
    and process CPU time (every thread) per frame."""
    from pipeline.ground import estimate_ground
    from pipeline.range_image import project
    from pipeline.segmentation import segment
    from pipeline.sequence import open_sequence

    opened = open_sequence(seq)
    source, sensor = opened.source, opened.sensor
    cfg = PipelineConfig()
    scans = [source.frame(i) for i in range(len(source))]
    wall, cpu = [], []
    for scan in scans:
        w0, c0 = time.perf_counter(), time.process_time()
        image = project(scan, sensor, cfg.range_image)
        g = estimate_ground(scan, image, cfg.ground)
        segment(image, scan.points, g.ground, sensor, cfg.segmentation)
        cpu.append(1e3 * (time.process_time() - c0))
        wall.append(1e3 * (time.perf_counter() - w0))
    return {
        "wall_median_ms": round(float(np.median(wall)), 3),
        "cpu_median_ms": round(float(np.median(cpu)), 3),
        "cpu_p95_ms": round(float(np.percentile(cpu, 95)), 3),
        "load_average_1min": os.getloadavg()[0],
    }


def run(out_dir: Path, quick: bool = False) -> dict:
    from research.simulation import simulate_sequence

    frames = 40 if quick else 200
    result: dict = {"frames": frames, "load_average_1min_start": os.getloadavg()[0]}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        seq = tmp / "sim"
        t0 = time.perf_counter()
        simulate_sequence(seq, frames=frames, seed=0)
        result["simulate_seconds"] = round(time.perf_counter() - t0, 2)
        # warm-up: numba kernels load from their cache (or compile) outside the timed runs
        run_process(seq, tmp / "warmup", PipelineConfig(), workers=1)
        result["pgs_isolated"] = _pgs_isolated(seq)
        runs = {}
        for size in (64, 256):
            cfg = PipelineConfig().override({"samples": {"size": size}})
            for workers in (1, 2):
                s = run_process(seq, tmp / f"out{size}_{workers}", cfg, workers=workers)
                runs[f"size{size}_workers{workers}"] = _pick(s)
        s = run_process(seq, tmp / "out64_written", PipelineConfig(), workers=2, samples=True)
        runs["size64_workers2_samples_written"] = _pick(s)
        result["process"] = runs
        result["load_average_1min"] = os.getloadavg()[0]
        ev = evaluate_folder(seq, tmp / "out64_1")
        result["evaluation"] = ev
        o = ev["overall"]
        best64 = max(runs["size64_workers1"]["frames_per_second"], runs["size64_workers2"]["frames_per_second"])
        best256 = max(runs["size256_workers1"]["frames_per_second"], runs["size256_workers2"]["frames_per_second"])
        result["targets"] = {
            "pgs_median_ms": {"value": runs["size64_workers1"]["ms_project_ground_segment"]["median"], "target": 5.0},
            "fps_64": {"value": best64, "target": 20.0},
            "fps_256": {"value": best256, "target": 10.0},
            "purity": {"value": o["purity"], "target": 0.97},
            "association_precision": {"value": o["association_precision"], "target": 0.99},
            "association_recall": {"value": o["association_recall"], "target": 0.90},
        }
        result["targets"]["pgs_median_ms"]["cpu_median_ms"] = result["pgs_isolated"]["cpu_median_ms"]
        for v in result["targets"].values():
            higher_is_better = v["target"] != 5.0
            v["met"] = v["value"] is not None and (
                v["value"] >= v["target"] if higher_is_better else v["value"] <= v["target"]
            )
        if not quick:
            # the same defaults on other simulated scenes: seed 1 was used with seed 0 to choose the
            # association thresholds; seeds 2 and 3 were only looked at afterwards (held out)
            for seed in (1, 2, 3):
                seq_s = tmp / f"sim{seed}"
                simulate_sequence(seq_s, frames=frames, seed=seed)
                run_process(seq_s, tmp / f"out_seed{seed}", PipelineConfig(), workers=1)
                o_s = evaluate_folder(seq_s, tmp / f"out_seed{seed}")["overall"]
                result[f"evaluation_seed{seed}_overall"] = o_s
                for name in ("association_precision", "association_recall", "purity"):
                    t = result["targets"][name]
                    t[f"value_seed{seed}"] = o_s[name]
                    t[f"met_seed{seed}"] = o_s[name] is not None and o_s[name] >= t["target"]
        real: dict = {}
        k = kitti_seq09(tmp / "kitti09")
        if k is not None:
            real["kitti_seq09_poses_file"] = _pick(run_process(k, tmp / "k_file", PipelineConfig()))
            real["kitti_seq09_poses_icp"] = _pick(run_process(k, tmp / "k_icp", PipelineConfig(), poses="icp"))
        nu = nuscenes_sweep()
        if nu is not None:
            real["nuscenes_hdl32e"] = _pick(run_process(nu, tmp / "nu", PipelineConfig()))
        result["real"] = real
    return result
