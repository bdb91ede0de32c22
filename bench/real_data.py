"""Builds sequence folders over ../shared/data/real for benchmarks (links only, nothing copied)."""

from __future__ import annotations

from pathlib import Path

REAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "real"
KITTI_TR = (
    "-1.857739385241e-03 -9.999659513510e-01 -8.039975204516e-03 -4.784029760483e-03 "
    "-6.481465826011e-03 8.051860151134e-03 -9.999466081774e-01 -7.337429464231e-02 "
    "9.999773098287e-01 -1.805528627661e-03 -6.496203536139e-03 -3.339968064433e-01"
)


def kitti_seq09(dest: Path, with_poses: bool = True, frames: range = range(10, 15)) -> Path | None:
    """A KITTI folder with frames 10..14 of sequence 09 (symlinks), poses.txt and calib.txt."""
    src = REAL / "kitti_seq09"
    if not src.is_dir():
        return None
    (dest / "velodyne").mkdir(parents=True, exist_ok=True)
    for i in frames:
        link = dest / "velodyne" / f"{i:06d}.bin"
        if not link.exists():
            link.symlink_to(src / "velodyne" / f"{i:06d}.bin")
    if with_poses:
        lines = (src / "kitti_odometry_gt_poses_09_with_time.txt").read_text().splitlines()
        (dest / "poses.txt").write_text("\n".join(" ".join(lines[i].split()[1:]) for i in frames) + "\n")
        (dest / "calib.txt").write_text(f"Tr: {KITTI_TR}\n")
    return dest


def nuscenes_sweep() -> Path | None:
    p = REAL / "nuscenes_hdl32e"
    files = sorted(p.glob("*.pcd.bin")) if p.is_dir() else []
    return files[0] if files else None


def kitti_seq00(dest: Path, frames: range = range(3)) -> Path | None:
    """A KITTI folder with the labelled frames of SemanticKITTI sequence 00 (symlinks to scans and
    labels), their poses, times and calib."""
    src = REAL / "kitti_seq00"
    if not src.is_dir():
        return None
    for sub, ext in (("velodyne", "bin"), ("labels", "label")):
        (dest / sub).mkdir(parents=True, exist_ok=True)
        for i in frames:
            link = dest / sub / f"{i:06d}.{ext}"
            if not link.exists():
                link.symlink_to(src / sub / f"{i:06d}.{ext}")
    for name in ("poses.txt", "times.txt"):
        lines = (src / name).read_text().splitlines()
        (dest / name).write_text("\n".join(lines[i] for i in frames) + "\n")
    calib = dest / "calib.txt"
    if not calib.exists():
        calib.symlink_to(src / "calib.txt")
    return dest
