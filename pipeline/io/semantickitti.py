"""SemanticKITTI files: `.bin` scans, `.label` labels, `poses.txt`, `calib.txt`, `times.txt`.

Low-level readers raise `DataError` naming the file; `write_sequence_frame` and friends write the
layout that `tracklabel simulate` and label exports produce::

    OUT/velodyne/NNNNNN.bin   float32 (N, 4): x, y, z, remission in [0, 1]
    OUT/labels/NNNNNN.label   uint32 (N,): semantic id (low 16 bits) | instance id << 16
    OUT/poses.txt             one 3x4 row-major pose per frame (camera frame, see calib.txt)
    OUT/calib.txt             `Tr: ...` velodyne -> camera, 3x4 row-major
    OUT/times.txt             one timestamp (s) per frame
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipeline.errors import DataError

BIN_RECORD = 4  # float32 values per point in a KITTI .bin


def frame_name(index: int) -> str:
    return f"{index:06d}"


def read_bin(path: str | Path, record: int = BIN_RECORD) -> np.ndarray:
    """(N, record) float32 rows of a `.bin` file; DataError if its size is not a whole record count."""
    path = Path(path)
    try:
        raw = np.fromfile(path, dtype=np.float32)
    except OSError as exc:
        raise DataError(path, f"cannot read: {exc}") from exc
    size = path.stat().st_size
    if size % (4 * record) != 0:
        raise DataError(path, f"size {size} bytes is not a multiple of the {4 * record}-byte point record")
    return raw.reshape(-1, record)


def read_label(path: str | Path, expected: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(semantic uint16 (N,), instance uint16 (N,)) of a `.label`; DataError on a bad size or count."""
    path = Path(path)
    size = path.stat().st_size
    if size % 4 != 0:
        raise DataError(path, f"size {size} bytes is not a multiple of 4 (uint32 labels)")
    raw = np.fromfile(path, dtype=np.uint32)
    if expected is not None and len(raw) != expected:
        raise DataError(path, f"has {len(raw)} labels but its scan has {expected} points")
    return (raw & 0xFFFF).astype(np.uint16), (raw >> 16).astype(np.uint16)


def pack_label(semantic: np.ndarray, instance: np.ndarray) -> np.ndarray:
    """uint32 labels from semantic (low 16 bits) and instance (high 16 bits) ids."""
    if np.any(np.asarray(instance) > 0xFFFF) or np.any(np.asarray(semantic) > 0xFFFF):
        raise ValueError("semantic and instance ids must fit in 16 bits")
    return (np.asarray(instance, dtype=np.uint32) << 16) | np.asarray(semantic, dtype=np.uint32)


def write_bin(path: str | Path, points: np.ndarray, remission: np.ndarray) -> None:
    """Write (N, 3) points and (N,) remission as a KITTI `.bin`."""
    assert points.ndim == 2 and points.shape[1] == 3 and remission.shape == (len(points),)
    rec = np.empty((len(points), 4), dtype=np.float32)
    rec[:, :3] = points
    rec[:, 3] = remission
    rec.tofile(path)


def write_label(path: str | Path, semantic: np.ndarray, instance: np.ndarray) -> None:
    pack_label(semantic, instance).tofile(path)


def read_matrix_lines(path: str | Path, values: int = 12) -> np.ndarray:
    """(L, 4, 4) float64 from lines of `values` numbers (12 = 3x4 row-major; 13 = time + 3x4)."""
    path = Path(path)
    rows = []
    for lineno, line in enumerate(path.read_text().splitlines(), start=1):
        if not line.strip():
            continue
        parts = line.split()
        try:
            nums = [float(x) for x in parts]
        except ValueError:
            raise DataError(path, f"line {lineno}: not numbers") from None
        if len(nums) != values:
            raise DataError(path, f"line {lineno}: expected {values} numbers, got {len(nums)}")
        rows.append(nums[-12:])
    mats = np.tile(np.eye(4), (len(rows), 1, 1))
    if rows:
        mats[:, :3, :4] = np.asarray(rows, dtype=np.float64).reshape(-1, 3, 4)
    if not np.isfinite(mats).all():
        raise DataError(path, "holds NaN or inf")
    return mats


def read_calib_tr(path: str | Path) -> np.ndarray:
    """(4, 4) `Tr` (velodyne -> camera) of a KITTI `calib.txt`."""
    path = Path(path)
    for line in path.read_text().splitlines():
        if line.startswith("Tr:"):
            nums = line.split()[1:]
            if len(nums) != 12:
                raise DataError(path, f"Tr has {len(nums)} numbers, expected 12")
            m = np.eye(4)
            m[:3, :4] = np.asarray([float(x) for x in nums]).reshape(3, 4)
            return m
    raise DataError(path, "no 'Tr:' line")


def lidar_poses(camera_poses: np.ndarray, tr: np.ndarray) -> np.ndarray:
    """`T_world_lidar` (F, 4, 4) from KITTI camera poses P_k: inv(Tr) @ P_k @ Tr."""
    return np.linalg.inv(tr)[None] @ camera_poses @ tr[None]


def write_poses(path: str | Path, poses: np.ndarray) -> None:
    """Write (F, 4, 4) poses as KITTI 3x4 row-major lines."""
    np.savetxt(path, poses[:, :3, :4].reshape(len(poses), 12), fmt="%.9e")


def write_calib_identity(path: str | Path) -> None:
    """A calib.txt whose Tr is the identity, so poses.txt already holds T_world_lidar."""
    eye = " ".join(f"{v:.12e}" for v in np.eye(4)[:3].ravel())
    Path(path).write_text(f"Tr: {eye}\n")


def write_times(path: str | Path, times: np.ndarray) -> None:
    np.savetxt(path, np.asarray(times, dtype=np.float64), fmt="%.6f")


def read_poses_file(path: Path, frames: int, calib: Path | None) -> tuple[np.ndarray, np.ndarray | None]:
    """(T_world_lidar (F, 4, 4), times (F,) or None) from a KITTI poses file (12 or 13 columns)
    and the `Tr` of `calib` (None = identity: the poses are the lidar's)."""
    first = next((ln for ln in path.read_text().splitlines() if ln.strip()), "")
    values = len(first.split())
    if values not in (12, 13):
        raise DataError(path, f"expected 12 numbers (3x4 pose) or 13 (time + pose) a line, got {values}")
    cam = read_matrix_lines(path, values=values)
    if len(cam) != frames:
        raise DataError(path, f"has {len(cam)} poses but the sequence has {frames} frames")
    tr = read_calib_tr(calib) if calib is not None else np.eye(4)
    times = None
    if values == 13:
        times = np.array([float(ln.split()[0]) for ln in path.read_text().splitlines() if ln.strip()])
    return lidar_poses(cam, tr), times


def read_times_file(path: Path, frames: int) -> np.ndarray:
    """(F,) float64 seconds from a `times.txt` of one time a line."""
    try:
        times = np.atleast_1d(np.loadtxt(path, dtype=np.float64))
    except ValueError as exc:
        raise DataError(path, f"not a column of numbers: {exc}") from None
    if times.ndim != 1 or len(times) != frames:
        raise DataError(path, f"has {times.size} times but the sequence has {frames} frames")
    return times


def sequence_poses(
    root: Path, frames: int, poses: str | Path | None = None, calib: str | Path | None = None
) -> tuple[tuple[np.ndarray | None, np.ndarray | None], str | None]:
    """((T_world_lidar (F, 4, 4) or None, times (F,) or None), warning or None) of a sequence
    folder `root` of `frames` frames: `poses` (default ROOT/poses.txt, absent = no poses) with
    `calib` (default ROOT/calib.txt; absent = identity, and a warning). A named file that does
    not exist is a DataError."""
    pose_file = Path(poses) if poses is not None else root / "poses.txt"
    if poses is None and not pose_file.is_file():
        return (None, None), None
    if not pose_file.is_file():
        raise DataError(pose_file, "no such poses file")
    calib_file = Path(calib) if calib is not None else root / "calib.txt"
    if calib is not None and not calib_file.is_file():
        raise DataError(calib_file, "no such calib file")
    warning = None
    if not calib_file.is_file():
        calib_file = None
        warning = f"{pose_file}: no calib.txt beside it, poses are taken as T_world_lidar"
    return read_poses_file(pose_file, frames, calib_file), warning


def folder_poses(
    path: Path, root: Path, frames: int, poses: str | Path | None, calib: str | Path | None, warnings: list[str]
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(T_world_lidar (F, 4, 4) or None, times (F,) or None) of the sequence at `path`, a folder
    or one frame file whose sequence folder is `root`: `sequence_poses`, with its warning added to
    `warnings`. A single file has poses only when they are named; a folder's times.txt wins over
    the times a poses file holds."""
    if poses is None and not path.is_dir():
        return None, None
    (pose_arr, times), warning = sequence_poses(root, frames, poses, calib)
    if warning:
        warnings.append(warning)
    if path.is_dir() and (root / "times.txt").is_file():
        times = read_times_file(root / "times.txt", frames)
    return pose_arr, times
