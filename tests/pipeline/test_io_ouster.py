from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import pipeline.io.ouster as ouster_module
from pipeline.errors import DataError
from pipeline.io import detect_format, open_reader
from pipeline.io.ouster import OusterSequence, find_ouster_metadata
from pipeline.odometry import estimate_poses

# (pcap, frames, beams, product) of ../shared/data/real/ouster
PCAPS = [
    ("OS-1-128_v2.3.0_1024x10_lb_n3.pcap", 3, 128, "ouster-os-1-128"),
    ("OS-1-32-G_v2.1.1_1024x10.pcap", 1, 32, "ouster-os-1-32-g"),
    ("OS-0-128-U1_v2.3.0_1024x10.pcap", 1, 128, "ouster-os-0-128"),
    ("OS-2-128-U1_v2.3.0_1024x10.pcap", 1, 128, "ouster-os-2-128"),
]


def row_elevations(scan, rows: int) -> np.ndarray:
    p = scan.points.astype(np.float64)
    el = np.degrees(np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1])))
    return np.array([np.median(el[scan.ring == r]) for r in range(rows) if (scan.ring == r).any()])


@pytest.mark.parametrize(("name", "frames", "beams", "product"), PCAPS)
def test_ouster_pcap_real(real_data: Path, name: str, frames: int, beams: int, product: str) -> None:
    path = real_data / "ouster" / name
    assert detect_format(path) == "ouster"
    seq = open_reader(path)
    assert len(seq) == frames and seq.sensor.name == product and seq.sensor.n_rings == beams
    scan = seq.frame(frames - 1)
    assert len(scan) > 0.5 * beams * 1024  # most pixels have a return
    assert scan.ring.min() == 0 and scan.ring.max() == beams - 1
    assert 0.0 <= scan.intensity.min() and scan.intensity.max() <= 1.0
    assert 0.0 <= scan.time.min() and scan.time.max() < 0.11  # one 10 Hz revolution
    # row 0 is the top beam: median elevation falls row by row (OS-0 has two parallax swaps low down)
    assert np.mean(np.diff(row_elevations(scan, beams)) < 0) > 0.97


def test_ouster_osf_real(real_data: Path) -> None:
    seq = open_reader(real_data / "ouster" / "osf_fw_3.2_10scans.osf")
    assert seq.format == "ouster" and len(seq) == 10
    assert (seq.sensor.name, seq.sensor.n_rings, seq.sensor.width) == ("ouster-os-0-8", 8, 2048)
    assert np.all(np.diff(seq.times) > 0.09) and np.all(np.diff(seq.times) < 0.11)
    scan = seq.frame(9)
    assert np.all(np.diff(row_elevations(scan, 8)) < 0)


def test_ouster_metadata_by_longest_prefix(real_data: Path) -> None:
    pcap = real_data / "ouster" / "OS-1-128_v2.3.0_1024x10_lb_n3.pcap"
    assert find_ouster_metadata(pcap).name == "OS-1-128_v2.3.0_1024x10.json"


def test_ouster_mismatched_metadata_names_file(real_data: Path) -> None:
    pcap = real_data / "ouster" / "OS-1-128_v2.3.0_1024x10_lb_n3.pcap"
    wrong = real_data / "ouster" / "OS-1-32-G_v2.1.1_1024x10.json"
    with pytest.raises(DataError, match="lb_n3.pcap: no complete scan"):
        OusterSequence(pcap, sensor_info=wrong)


def test_ouster_folder_with_many_recordings(real_data: Path) -> None:
    with pytest.raises(DataError, match="holds 5 .pcap/.osf recordings"):
        OusterSequence(real_data / "ouster")


def test_ouster_pcap_without_metadata(tmp_path: Path) -> None:
    (tmp_path / "x.pcap").write_bytes(b"\xd4\xc3\xb2\xa1")
    with pytest.raises(DataError, match="no Ouster metadata"):
        OusterSequence(tmp_path / "x.pcap")


def test_ouster_sdk_missing_is_data_error(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "x.osf").write_bytes(b"")
    monkeypatch.setattr(ouster_module, "_sdk", lambda: None)
    with pytest.raises(DataError, match=r"tracklabel\[ouster\]"):
        OusterSequence(tmp_path / "x.osf")


def test_ouster_corrupt_pcap_names_file(tmp_path: Path) -> None:
    (tmp_path / "x.pcap").write_bytes(b"not a pcap at all")
    (tmp_path / "x.json").write_text(json.dumps({"lidar_mode": "1024x10"}))
    with pytest.raises(DataError, match="x.pcap"):
        OusterSequence(tmp_path / "x.pcap")


def test_estimate_poses_deskews_ouster_scans(real_data: Path) -> None:
    """Per-point times switch deskewing on; three 10 Hz scans of a moving sensor give small motions."""
    seq = open_reader(real_data / "ouster" / "OS-1-128_v2.3.0_1024x10_lb_n3.pcap")
    assert seq.frame(0).time is not None
    poses = estimate_poses(seq)
    steps = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1)
    assert np.isfinite(poses).all() and np.all(steps < 2.0)
