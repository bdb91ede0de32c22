"""The real-data folders the benchmarks build: labels carried along kitti_seq00 through the poses."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline.classes import GROUND, to_ours


@pytest.mark.real_data
def test_labels_carried_from_frame_0_agree_with_frames_1_and_2s_own(real_data: Path) -> None:
    from bench.real_data import propagated_labels

    carried = propagated_labels([1, 2], radius=0.2, sources=range(1))
    for i, lab in carried.items():
        own = to_ours(np.fromfile(real_data / "kitti_seq00" / "labels" / f"{i:06d}.label", np.uint32) & 0xFFFF)
        got = to_ours(lab & 0xFFFF)
        thing = ((lab & 0xFFFF) > 0) & (got != GROUND)
        assert thing.sum() > 30_000  # most of the non-ground surface frame 0 saw
        assert np.mean(got[thing] == own[thing]) > 0.95, i
        assert not ((lab & 0xFFFF) >= 252).any()  # moving objects (frame 0 has a moving motorcyclist) carry nothing


@pytest.mark.real_data
def test_propagated_folder_links_own_labels_and_writes_the_others(real_data: Path, tmp_path: Path) -> None:
    from bench.real_data import kitti_seq00_propagated

    seq = kitti_seq00_propagated(tmp_path / "k00", frames=range(12), radius=0.2)
    labels = sorted(p.name for p in (seq / "labels").iterdir())
    assert labels == [f"{i:06d}.label" for i in range(12)]
    assert (seq / "labels" / "000009.label").is_symlink() and not (seq / "labels" / "000011.label").is_symlink()
    n11 = len(np.fromfile(seq / "velodyne" / "000011.bin", np.float32)) // 4
    assert len(np.fromfile(seq / "labels" / "000011.label", np.uint32)) == n11
    assert len((seq / "poses.txt").read_text().splitlines()) == 12
