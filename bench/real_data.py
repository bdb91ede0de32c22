"""Builds sequence folders over ../shared/data/real for benchmarks (links only, nothing copied)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

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
        for i in frames:
            _link(dest / sub / f"{i:06d}.{ext}", src / sub / f"{i:06d}.{ext}")
    _kitti_metadata(dest, src, frames)
    return dest


def _link(link: Path, target: Path) -> None:
    link.parent.mkdir(parents=True, exist_ok=True)
    if not link.exists():
        link.symlink_to(target)


def _kitti_metadata(dest: Path, src: Path, frames: range | list[int]) -> None:
    """poses.txt and times.txt of `frames`, calib.txt linked."""
    for name in ("poses.txt", "times.txt"):
        lines = (src / name).read_text().splitlines()
        (dest / name).write_text("\n".join(lines[i] for i in frames) + "\n")
    _link(dest / "calib.txt", src / "calib.txt")


def _kitti_lidar_poses(src: Path, frames: range) -> list[np.ndarray]:
    """(4, 4) LiDAR poses of `frames` of a KITTI folder: inv(Tr) @ P_k @ Tr (SOURCES.md)."""
    tr_line = next(ln for ln in (src / "calib.txt").read_text().splitlines() if ln.startswith("Tr:"))
    tr = np.eye(4)
    tr[:3] = np.array(tr_line.split()[1:], float).reshape(3, 4)
    lines = (src / "poses.txt").read_text().splitlines()
    out = []
    for i in frames:
        p = np.eye(4)
        p[:3] = np.array(lines[i].split(), float).reshape(3, 4)
        out.append(np.linalg.inv(tr) @ p @ tr)
    return out


def _world_points(src: Path, i: int, pose: np.ndarray) -> np.ndarray:
    xyz = np.fromfile(src / "velodyne" / f"{i:06d}.bin", np.float32).reshape(-1, 4)[:, :3].astype(np.float64)
    return xyz @ pose[:3, :3].T + pose[:3, 3]


LABELLED_00 = range(10)  # the frames of kitti_seq00 with their own SemanticKITTI labels


def propagated_labels(frames: range | list[int], radius: float = 0.15, sources: range = LABELLED_00) -> dict[int, np.ndarray]:
    """SemanticKITTI labels (uint32 per point) for `frames` of kitti_seq00, carried from the
    labelled `sources` through the ground-truth poses: a point takes the label of the nearest
    labelled point within `radius` metres in the world frame, else 0 (unlabelled). Moving objects
    (classes 252-259) and unlabelled points carry nothing: a point whose nearest source point is
    one of them stays unlabelled. An approximation for development: static surfaces seen in the
    labelled frames get their labels, anything they did not see stays unlabelled."""
    from scipy.spatial import cKDTree

    src = REAL / "kitti_seq00"
    poses = _kitti_lidar_poses(src, range(max(max(frames), max(sources)) + 1))
    pts = [_world_points(src, i, poses[i]) for i in sources]
    lab = [np.fromfile(src / "labels" / f"{i:06d}.label", np.uint32) for i in sources]
    pts_all, lab_all = np.concatenate(pts), np.concatenate(lab)
    tree = cKDTree(pts_all)
    carries = ((lab_all & 0xFFFF) < 252) & ((lab_all & 0xFFFF) != 0)
    out = {}
    for i in frames:
        dist, nn = tree.query(_world_points(src, i, poses[i]), k=1, distance_upper_bound=radius, workers=-1)
        found = np.isfinite(dist)
        keep = np.zeros(len(dist), bool)
        keep[found] = carries[nn[found]]
        out[i] = np.where(keep, lab_all[np.minimum(nn, len(lab_all) - 1)], 0).astype(np.uint32)
    return out


def kitti_seq00_propagated(dest: Path, frames: range = range(60), radius: float = 0.15) -> Path | None:
    """A KITTI folder with `frames` of sequence 00 (scans linked): the labelled frames' own labels
    linked, the others' carried from them (`LABELLED_00`) through the poses (`propagated_labels`)
    and written under `dest` (never into ../shared)."""
    src = REAL / "kitti_seq00"
    if not src.is_dir():
        return None
    own = [i for i in frames if (src / "labels" / f"{i:06d}.label").exists()]
    for i in frames:
        _link(dest / "velodyne" / f"{i:06d}.bin", src / "velodyne" / f"{i:06d}.bin")
    for i in own:
        _link(dest / "labels" / f"{i:06d}.label", src / "labels" / f"{i:06d}.label")
    others = [i for i in frames if i not in own]
    for i, lab in (propagated_labels(others, radius) if others else {}).items():
        lab.tofile(dest / "labels" / f"{i:06d}.label")
    _kitti_metadata(dest, src, frames)
    return dest


# The labelled real clips the perception defaults are chosen and checked on, all together
# (SOURCES.md): SemanticKITTI 00 (a street of parked cars, hedges and walls), 01 (a highway: fast
# cars both ways) and 02 (a suburban road with vegetation), frames 0-9 of each.
CLIPS = ("kitti_seq00", "kitti_seq01", "kitti_seq02")
CLIP_FRAMES = range(10)


def labelled_clips(dest: Path, frames: range = CLIP_FRAMES) -> dict[str, Path]:
    """{clip: KITTI folder} of `frames` of each labelled clip (scans, labels, poses, times and
    calib linked or cut under `dest`); {} when ../shared is absent."""
    out = {}
    for name in CLIPS:
        src = REAL / name
        if not (src / "velodyne").is_dir():
            continue
        dst = dest / name
        for sub, ext in (("velodyne", "bin"), ("labels", "label")):
            for i in frames:
                _link(dst / sub / f"{i:06d}.{ext}", src / sub / f"{i:06d}.{ext}")
        _kitti_metadata(dst, src, frames)
        out[name] = dst
    return out
