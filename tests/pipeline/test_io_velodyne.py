"""Velodyne pcap reader, on an HDL-32E pcap crafted here (no real Velodyne pcap is available)."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

import pipeline.io.velodyne as velodyne_module
from pipeline.errors import DataError
from pipeline.io import detect_format, open_reader
from pipeline.io.velodyne import VelodynePcapSequence

BLOCK_DT = 46.08e-6  # s between HDL-32E firing blocks


def _frame(payload: bytes, stamp: float) -> bytes:
    udp = struct.pack(">HHHH", 2368, 2368, 8 + len(payload), 0) + payload
    ip = struct.pack(
        ">BBHHHBBH4s4s", 0x45, 0, 20 + len(udp), 0, 0x4000, 64, 17, 0, bytes([192, 168, 1, 201]), b"\xff" * 4
    )
    eth = b"\xff" * 6 + b"\x60\x76\x88\x00\x00\x00" + b"\x08\x00" + ip + udp
    sec, usec = int(stamp), int(round((stamp % 1) * 1e6)) % 1_000_000
    return struct.pack("<IIII", sec, usec, len(eth), len(eth)) + eth


def write_hdl32e_pcap(path: Path, revolutions: float = 2.2, distance_m: float = 10.0) -> Path:
    """HDL-32E data packets at 10 Hz: every laser at `distance_m`, laser k with intensity 4 k."""
    step = 360.0 * 10.0 * BLOCK_DT  # degrees per firing block
    blocks = int(revolutions * 360.0 / step) // 12 * 12
    out = bytearray(struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 65535, 1))  # pcap, Ethernet
    lasers = b"".join(struct.pack("<HB", int(distance_m / 0.002), 4 * k) for k in range(32))
    for p in range(blocks // 12):
        payload = bytearray()
        for b in range(12):
            azimuth = int(round(((p * 12 + b) * step % 360.0) * 100)) % 36000
            payload += struct.pack("<HH", 0xEEFF, azimuth) + lasers
        t_us = int(p * 12 * BLOCK_DT * 1e6)
        payload += struct.pack("<IBB", t_us, 0x37, 0x21)  # strongest return, HDL-32E
        out += _frame(bytes(payload), 1_600_000_000 + t_us * 1e-6)
    path.write_bytes(bytes(out))
    return path


@pytest.fixture
def hdl32e_pcap(tmp_path: Path) -> Path:
    pytest.importorskip("velodyne_decoder")
    return write_hdl32e_pcap(tmp_path / "hdl32e.pcap")


def test_velodyne_pcap_detected_without_json(hdl32e_pcap: Path) -> None:
    assert detect_format(hdl32e_pcap) == "velodyne_pcap"


def test_velodyne_pcap_decodes_scans(hdl32e_pcap: Path) -> None:
    seq = open_reader(hdl32e_pcap)
    assert len(seq) == 3  # two revolutions and the partial one at the end
    assert seq.sensor.name == "hdl32e" and seq.poses is None
    assert np.diff(seq.times) == pytest.approx([0.1, 0.0188], abs=2e-3)
    scan = seq.frame(0)
    assert len(scan) > 32 * 2000
    np.testing.assert_allclose(np.linalg.norm(scan.points, axis=1), 10.0, atol=0.1)
    assert 0.0 == scan.time.min() and scan.time.max() == pytest.approx(0.1, abs=2e-3)


def test_velodyne_pcap_row0_is_top_beam(hdl32e_pcap: Path) -> None:
    scan = open_reader(hdl32e_pcap).frame(0)
    p = scan.points.astype(np.float64)
    el = np.degrees(np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1])))
    med = np.array([np.median(el[scan.ring == r]) for r in range(32)])
    assert np.all(np.diff(med) < 0)
    assert med[0] == pytest.approx(10.67, abs=0.2) and med[31] == pytest.approx(-30.67, abs=0.2)
    # HDL-32E laser 0 is the lowest beam (intensity 0), laser 31 the top one (intensity 124)
    assert np.all(scan.intensity[scan.ring == 31] == 0.0)
    assert np.allclose(scan.intensity[scan.ring == 0], 124 / 255)


def test_velodyne_pcap_frames_out_of_order(hdl32e_pcap: Path) -> None:
    seq = VelodynePcapSequence(hdl32e_pcap)
    later, earlier, again = seq.frame(2), seq.frame(1), seq.frame(2)
    assert len(later) < len(earlier)
    np.testing.assert_array_equal(later.points, again.points)
    with pytest.raises(IndexError):
        seq.frame(3)


def test_velodyne_pcap_corrupt_names_file(tmp_path: Path) -> None:
    pytest.importorskip("velodyne_decoder")
    f = tmp_path / "bad.pcap"
    f.write_bytes(b"this is not a pcap file")
    with pytest.raises(DataError, match="bad.pcap: cannot decode"):
        VelodynePcapSequence(f)


def test_velodyne_pcap_without_velodyne_packets(tmp_path: Path) -> None:
    pytest.importorskip("velodyne_decoder")
    f = tmp_path / "other.pcap"
    header = struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 65535, 1)
    f.write_bytes(header + _frame(b"hello", 1.0) + _frame(b"world", 2.0))
    with pytest.raises(DataError, match="other.pcap: no Velodyne scan decoded"):
        VelodynePcapSequence(f)


def test_velodyne_decoder_missing_is_data_error(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    f = tmp_path / "x.pcap"
    f.write_bytes(b"")
    monkeypatch.setattr(velodyne_module, "_decoder", lambda: None)
    with pytest.raises(DataError, match=r"tracklabel\[velodyne\]"):
        VelodynePcapSequence(f)
