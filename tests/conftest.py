from __future__ import annotations

import os
import tempfile
from pathlib import Path

import pytest

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
REAL = SHARED / "data" / "real"
# Screenshots that tests take go here (ignored by git); `make screenshots` refreshes docs/'s.
SCREENSHOTS = Path(os.environ.get("TRACKLABEL_SCREENSHOT_DIR") or Path(__file__).resolve().parents[1] / "build" / "screenshots")


def pytest_configure(config: pytest.Config) -> None:
    """Point the per-user data folder (app.core.config.default_data_dir) at a temporary one, for
    this process and the commands tests start, so that no test reads or writes the user's own."""
    os.environ["XDG_DATA_HOME"] = tempfile.mkdtemp(prefix="tracklabel-test-xdg-")


@pytest.fixture(scope="session")
def real_data() -> Path:
    """../shared/data/real, or skip when this clone has no shared folder beside it."""
    if not REAL.is_dir():
        pytest.skip("../shared/data/real is absent")
    return REAL


# KITTI odometry Tr (velodyne -> cam0) of the 2011_09_30 rig, from ../shared/data/real/SOURCES.md.
KITTI_SEQ09_TR = (
    "-1.857739385241e-03 -9.999659513510e-01 -8.039975204516e-03 -4.784029760483e-03 "
    "-6.481465826011e-03 8.051860151134e-03 -9.999466081774e-01 -7.337429464231e-02 "
    "9.999773098287e-01 -1.805528627661e-03 -6.496203536139e-03 -3.339968064433e-01"
)


@pytest.fixture(scope="session")
def kitti_seq09(real_data: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A KITTI sequence folder of frames 10..14 of sequence 09 (symlinks to the real scans),
    with poses.txt (ground-truth camera poses, time column dropped) and calib.txt (Tr)."""
    src = real_data / "kitti_seq09"
    dest = tmp_path_factory.mktemp("kitti_seq09")
    (dest / "velodyne").mkdir()
    frames = range(10, 15)
    for i in frames:
        (dest / "velodyne" / f"{i:06d}.bin").symlink_to(src / "velodyne" / f"{i:06d}.bin")
    lines = (src / "kitti_odometry_gt_poses_09_with_time.txt").read_text().splitlines()
    (dest / "poses.txt").write_text("\n".join(" ".join(lines[i].split()[1:]) for i in frames) + "\n")
    (dest / "calib.txt").write_text(f"Tr: {KITTI_SEQ09_TR}\n")
    return dest
