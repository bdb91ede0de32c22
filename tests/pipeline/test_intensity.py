"""Intensity per sensor (pipeline.intensity), the training inputs' statistics and the warnings
predict gives (pipeline.input_stats), and the intensity augmentation of training."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from pipeline.input_stats import canvas_stats, input_warnings, sensor_intensity_stats
from pipeline.intensity import NONE, RAW, REFERENCE, SCALE, canvas_mode, is_absent, measure, normalised, scale
from pipeline.training import vary_intensity


def _cloud(n: int = 2000, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    az = rng.uniform(0, 2 * np.pi, n)
    pts = np.stack([10 * np.cos(az), 10 * np.sin(az), rng.uniform(-1, 1, n)], axis=1).astype(np.float32)
    return pts, rng.uniform(0.0, 1.0, n).astype(np.float32) ** 2


def test_intensity_scaled_per_sensor_does_not_change_when_a_sensor_rescales_its_values():
    pts, inten = _cloud()
    shown = []
    for factor in (1.0, 0.01, 255.0):  # KITTI's remission, an Ouster's reflectivity / 65535, 8-bit counts
        mode, scale = canvas_mode("sensor", measure(pts, inten * factor))
        assert mode == SCALE
        shown.append(np.array([normalised(float(v) * factor, mode, scale) for v in inten[:200]]))
    assert np.allclose(shown[0], shown[1], atol=1e-3) and np.allclose(shown[0], shown[2], atol=1e-3)
    assert shown[0].min() >= 0.0 and shown[0].max() <= 1.0
    # the sensor's 95th percentile reads REFERENCE; the contrast within the sensor stays
    mode, scale = canvas_mode("sensor", measure(pts, inten))
    assert normalised(float(np.percentile(inten, 95)), mode, scale) == pytest.approx(REFERENCE, abs=0.02)
    assert np.corrcoef(shown[0], inten[:200])[0, 1] > 0.99


def test_intensity_absent_gives_an_empty_channel_and_unmeasured_stays_raw():
    pts, _ = _cloud()
    q = measure(pts, np.zeros(len(pts), np.float32))
    assert is_absent(q) and canvas_mode("sensor", q)[0] == NONE
    assert normalised(0.7, *canvas_mode("sensor", q)) == 0.0
    assert canvas_mode("sensor", ())[0] == RAW and canvas_mode("raw", measure(*_cloud()))[0] == RAW
    assert normalised(1.7, RAW, 1.0) == 1.0
    assert measure(pts[:50], np.ones(50, np.float32)) == ()  # too few points to measure


def test_intensity_scale_of_a_sensor_that_mostly_reports_zero():
    # 96 % of the returns read 0 (an Ouster whose reflectivity was stored as counts / 65535):
    # the scale comes from the largest positive quantile, never a division by 0
    pts, inten = _cloud(3000)
    inten[: int(0.96 * len(inten))] = 0.0
    q = measure(pts, inten)
    assert not is_absent(q) and np.isfinite(scale(q)) and scale(q) > 0


def _canvases(n: int, intensity: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    x = np.zeros((n, 4, 8, 8), np.uint8)
    x[:, 0, 2:6, 2:6] = rng.integers(20, 60, (n, 4, 4))
    x[:, 1, 2:6, 2:6] = rng.integers(30, 90, (n, 4, 4))
    if intensity:  # a spread of canvases around `intensity`
        x[:, 2, 2:6, 2:6] = np.clip(intensity + rng.integers(-60, 60, (n, 1, 1)), 1, 255)
    x[:, 3, 3:5, 3:5] = 255
    return x


def test_input_warnings_name_the_channel_outside_the_training_data():
    stats = canvas_stats(_canvases(300, 128)) | {"sensor_intensity": sensor_intensity_stats([(0.0, 0.1, 0.3, 0.6, 1.0)])}
    assert set(stats["channels"]) == {"height", "range", "intensity", "foreground"}
    kitti_like = (0.0, 0.2, 0.3, 0.4, 1.0)
    assert input_warnings(stats, _canvases(50, 120, seed=1), kitti_like) == []
    # an Ouster read as a .bin: every intensity under 0.01
    ouster = input_warnings(stats, _canvases(50, 120, seed=1), (0.0, 0.002, 0.004, 0.006, 0.01))
    assert len(ouster) == 1 and ouster[0].startswith("intensity:") and "scaled per sensor" in ouster[0]
    # xyz only: no intensity; the empty canvas channel is expected then and not reported twice
    xyz = input_warnings(stats, _canvases(50, 0, seed=1), (0.0,) * 5)
    assert len(xyz) == 1 and xyz[0].startswith("intensity: the input has none")
    # canvases whose range channel lies far out (a sensor seen at ten times the training range)
    far = _canvases(50, 120, seed=1)
    far[:, 1][far[:, 1] > 0] = 250
    assert [w.split(":")[0] for w in input_warnings(stats, far, kitti_like)] == ["range"]
    assert input_warnings({}, far, kitti_like) == []  # an older checkpoint: nothing to compare with


def test_vary_intensity_drops_or_bends_only_the_intensity_channel():
    x = torch.rand(400, 4, 8, 8)
    out = vary_intensity(x, 0.25, 1.0, torch.Generator().manual_seed(0))
    assert torch.equal(out[:, [0, 1, 3]], x[:, [0, 1, 3]])
    dropped = (out[:, 2] == 0).flatten(1).all(dim=1)
    assert 0.15 < dropped.float().mean() < 0.35
    kept = ~dropped
    # each kept canvas is x ** p with one p in [0.5, 2]: monotonic, ranks unchanged
    a, b = x[kept][:, 2].flatten(1), out[kept][:, 2].flatten(1)
    assert torch.equal(a.argsort(dim=1), b.argsort(dim=1))
    assert not torch.allclose(a, b)


def _top_share(summary: dict) -> float:
    points = {k: v for k, v in summary["points"].items() if k not in ("ground", "unlabelled")}
    return max(points.values()) / sum(points.values())


@pytest.mark.real_data
def test_shipped_model_on_an_xyz_only_scan_warns_about_intensity_and_calls_not_all_one_class(real_data, tmp_path):
    # the nuScenes sweep's x, y, z alone as a PCD: the first shipped model called 173 of its 175
    # segments car and said nothing
    from pypcd4 import PointCloud

    from pipeline.pipeline import PredictOptions, run_predict

    raw = np.fromfile(next((real_data / "nuscenes_hdl32e").glob("*.pcd.bin")), np.float32).reshape(-1, 5)
    (tmp_path / "xyz").mkdir()
    PointCloud.from_xyz_points(np.ascontiguousarray(raw[:, :3])).save(tmp_path / "xyz" / "0.pcd")
    logged: list[str] = []
    summary = run_predict(tmp_path / "xyz", None, tmp_path / "out", PredictOptions(device="cpu"), log=logged.append)
    assert any(w.startswith("intensity: the input has none") for w in summary["warnings"])
    assert set(summary["warnings"]) <= set(logged)
    assert _top_share(summary) <= 0.6


@pytest.mark.real_data
def test_shipped_model_on_an_ouster_capture_warns_about_intensity_and_calls_not_all_one_class(real_data, tmp_path):
    pytest.importorskip("ouster.sdk")
    from pipeline.pipeline import PredictOptions, run_predict

    pcap = real_data / "ouster" / "OS-1-128_v2.3.0_1024x10_lb_n3.pcap"
    summary = run_predict(pcap, None, tmp_path / "out", PredictOptions(device="cpu"))
    assert [w.split(":")[0] for w in summary["warnings"]] == ["intensity"]
    assert _top_share(summary) <= 0.6
