"""Online inference throughput: `tracklabel predict` (pipeline.pipeline.run_predict) in frames/s.

Simulates 100 frames (30 with --quick) of seed 0 into a temporary folder, writes an untrained
checkpoint of the default model at S=64 (speed does not depend on the weights) and runs the
whole prediction: read, segment, render samples, associate, classify, write labels, confidences
and per-segment probabilities. Reported with torch's default threads and with 1 thread, on CPU
(and CUDA when present). Target (issue 5): >= 10 frames/s on CPU with 64x64 samples.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import torch

from pipeline.config import ModelConfig, SampleConfig
from pipeline.model import get_model, save_checkpoint
from pipeline.pipeline import PredictOptions, run_predict
from research.simulation import simulate_sequence

TARGET_FPS = 10.0


def _run(seq: Path, ckpt: Path, out: Path, device: str, threads: int) -> dict:
    before = torch.get_num_threads()
    if threads:
        torch.set_num_threads(threads)
    try:
        s = run_predict(seq, ckpt, out, PredictOptions(device=device, evaluate=False))
    finally:
        torch.set_num_threads(before)
    return {
        "device": device,
        "threads": threads or before,
        "frames": s["frames"],
        "segments": sum(s["segments_classified"].values()),
        "seconds": s["seconds"],
        "seconds_classify": s["seconds_classify"],
        "seconds_write": s["seconds_write"],
        "frames_per_s": s["frames_per_second"],
    }


def run(out_dir: Path, quick: bool = False) -> dict:
    frames = 30 if quick else 100
    with tempfile.TemporaryDirectory() as tmp:
        tmp_path = Path(tmp)
        seq = tmp_path / "seq"
        simulate_sequence(seq, frames=frames, seed=0)
        samples = SampleConfig(size=64)
        ckpt = save_checkpoint(tmp_path / "m.pt", get_model(ModelConfig(), samples), ModelConfig(), samples)
        run_predict(seq, ckpt, tmp_path / "warm", PredictOptions(evaluate=False))  # torch start-up, numba caches
        runs = [_run(seq, ckpt, tmp_path / "o1", "cpu", 0), _run(seq, ckpt, tmp_path / "o2", "cpu", 1)]
        if torch.cuda.is_available():
            runs.append(_run(seq, ckpt, tmp_path / "o3", "cuda", 0))
    best = max(r["frames_per_s"] for r in runs if r["device"] == "cpu")
    return {
        "sample_size": 64,
        "runs": runs,
        "headline": f"predict {best:.1f} frames/s on CPU at S=64 "
        f"({runs[0]['segments'] / max(runs[0]['frames'], 1):.0f} segments/frame)",
        "targets": {"predict_frames_per_s_cpu_s64": {"value": best, "target": TARGET_FPS, "met": best >= TARGET_FPS}},
    }
