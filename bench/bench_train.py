"""Training and classification throughput of the sample CNN (issue 5).

Measures `pipeline.training.train` on random canvases (speed does not depend on content): the
default model and batch (m labelled + 2 x pairs_per_label x m pair samples per step), one warm-up
epoch, then a timed epoch. S=64 uses the configured batch; S=256 uses m=8 (88 canvases per step)
and fewer steps to keep memory and time bounded. Reports canvases through forward+backward per
second of wall time and per CPU second, labels-only steps, and `predict` throughput; S=64 training
runs with 1 and with 2 torch threads (on a busy 2-core machine 2 threads can be slower than 1).
Repeats on CUDA when present.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch

from pipeline.config import ModelConfig, SampleConfig, TrainingConfig
from pipeline.model import NetConfig, build_model, predict, resolve_device
from pipeline.training import TrainingData, train


def _data(size: int, channels: int, n: int, n_pairs: int, with_pairs: bool) -> TrainingData:
    rng = np.random.default_rng(0)
    x = rng.integers(0, 256, (n, channels, size, size), dtype=np.uint8)
    y = rng.integers(0, 7, n)
    pairs = rng.integers(0, n, (n_pairs, 2)) if with_pairs else None
    return TrainingData.build(x, np.arange(n), y, pairs)


def _train_speed(size: int, batch: int, steps: int, with_pairs: bool, device: str, threads: int = 0) -> dict:
    samples = SampleConfig(size=size)
    model = ModelConfig()
    cfg = TrainingConfig(
        epochs=2, steps_per_epoch=steps, batch_labelled=batch, device=device, eval_batch=64, threads=threads
    )
    data = _data(size, samples.channels, 256, 1024, with_pairs)
    cpu0 = time.process_time()
    res = train(data, cfg, model, samples)
    cpu = time.process_time() - cpu0
    timed = res.history[-1]  # epoch 0 is the warm-up
    per_step = batch * (1 + 2 * cfg.pairs_per_label) if with_pairs else batch
    total = per_step * steps * len(res.history)
    return {
        "size": size,
        "device": device,
        "threads": threads or torch.get_num_threads(),
        "canvases_per_step": per_step,
        "steps_timed": steps,
        "samples_per_s": round(timed.samples_per_s, 1),
        "steps_per_s": round(timed.samples_per_s / per_step, 3),
        "samples_per_cpu_s": round(total / cpu, 1) if device == "cpu" else None,
    }


def _predict_speed(size: int, n: int, device: str) -> dict:
    samples = SampleConfig(size=size)
    net = build_model(NetConfig.from_configs(ModelConfig(), samples)).to(resolve_device(device))
    x = np.random.default_rng(1).integers(0, 256, (n, samples.channels, size, size), dtype=np.uint8)
    predict(net, x[:32])  # warm-up
    t0 = time.perf_counter()
    predict(net, x)
    return {"size": size, "device": device, "samples": n, "samples_per_s": round(n / (time.perf_counter() - t0), 1)}


def run(out_dir: Path, quick: bool = False) -> dict:
    devices = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
    net64 = build_model(NetConfig.from_configs(ModelConfig(), SampleConfig(size=64)))
    result: dict = {
        "torch": torch.__version__,
        "threads": torch.get_num_threads(),
        "model": ModelConfig().model_dump(),
        "parameters": net64.num_parameters(),
        "train": [],
        "train_labels_only": [],
        "predict": [],
    }
    steps64, steps256 = (3, 1) if quick else (8, 2)
    batch = TrainingConfig().batch_labelled
    result["train"].append(_train_speed(64, batch, steps64, True, "cpu", threads=1))
    for dev in devices:
        result["train"].append(_train_speed(64, batch, steps64, True, dev))
        result["train"].append(_train_speed(256, 8, steps256, True, dev))
        result["train_labels_only"].append(_train_speed(64, batch, steps64, False, dev))
        result["predict"].append(_predict_speed(64, 512 if quick else 2048, dev))
        result["predict"].append(_predict_speed(256, 32 if quick else 128, dev))
    one, cpu64, cpu256 = result["train"][:3]
    result["headline"] = (
        f"train S=64 {cpu64['samples_per_s']:.0f} samples/s on CPU ({cpu64['threads']} threads; "
        f"{one['samples_per_s']:.0f} with 1), S=256 {cpu256['samples_per_s']:.0f}; "
        f"predict S=64 {result['predict'][0]['samples_per_s']:.0f} samples/s"
    )
    return result
