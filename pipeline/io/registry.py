"""The registry of sequence readers: one module per source, registered by name."""

from __future__ import annotations

import importlib
from collections.abc import Callable, Iterable
from pathlib import Path

from natsort import natsorted

from pipeline.errors import DataError
from pipeline.scan import SequenceSource

# name -> "module:callable"; modules import lazily so optional extras stay optional.
_READERS: dict[str, str] = {
    "kitti": "pipeline.io.kitti:KittiSequence",
    "nuscenes": "pipeline.io.nuscenes:NuScenesSequence",
    "pcd": "pipeline.io.pointfiles:PcdSequence",
    "ply": "pipeline.io.pointfiles:PlySequence",
    "ouster": "pipeline.io.ouster:OusterSequence",
    "velodyne_pcap": "pipeline.io.velodyne:VelodynePcapSequence",
}


def frame_files(paths: Iterable[Path]) -> list[Path]:
    """Frame files in natural order of their names (`9.pcd` before `10.pcd`; zero-padded names
    sort as before)."""
    return natsorted(paths, key=lambda p: p.name)


def register_reader(name: str, target: str) -> None:
    """Register a reader `module:callable` under `name`."""
    _READERS[name] = target


def reader_names() -> list[str]:
    return sorted(_READERS)


def _load(name: str) -> Callable[..., SequenceSource]:
    try:
        target = _READERS[name]
    except KeyError:
        raise KeyError(f"unknown format {name!r}; known: {', '.join(reader_names())}") from None
    module, attr = target.split(":")
    return getattr(importlib.import_module(module), attr)


def dataset_factory(name: str, path: str | Path, **opts: object) -> SequenceSource:
    """Open `path` with the reader registered as `name`."""
    return _load(name)(Path(path), **opts)


def _pcap_format(pcap: Path) -> str:
    """Ouster when a metadata json goes with the pcap, else Velodyne."""
    from pipeline.io.ouster import find_ouster_metadata  # imports no SDK

    return "ouster" if find_ouster_metadata(pcap) is not None else "velodyne_pcap"


def detect_format(path: str | Path) -> str:
    """Guess the format of a file or folder; raises DataError naming the path when unknown."""
    p = Path(path)
    if not p.exists():
        raise DataError(p, "no such file or folder")
    if p.is_dir():
        if (p / "velodyne").is_dir() or any(p.glob("*.bin")):
            if any(p.glob("*.pcd.bin")):
                return "nuscenes"
            return "kitti"
        if any(p.glob("*.pcd")):
            return "pcd"
        if any(p.glob("*.ply")):
            return "ply"
        if any(p.glob("*.osf")):
            return "ouster"
        pcaps = frame_files(p.glob("*.pcap"))
        if pcaps:
            return _pcap_format(pcaps[0])
        if not any(p.iterdir()):
            raise DataError(p, "folder is empty")
        raise DataError(p, "unknown folder layout: expected velodyne/*.bin, *.pcd.bin, *.pcd, *.ply or *.pcap")
    name = p.name.lower()
    if name.endswith(".pcd.bin"):
        return "nuscenes"
    if name.endswith(".bin"):
        return "kitti"
    if name.endswith(".pcd"):
        return "pcd"
    if name.endswith(".ply"):
        return "ply"
    if name.endswith(".osf"):
        return "ouster"
    if name.endswith(".pcap"):
        return _pcap_format(p)
    raise DataError(p, "unknown file type")


def open_reader(path: str | Path, fmt: str = "auto", **opts: object) -> SequenceSource:
    """The reader of `path`, detecting its format unless `fmt` names one (the pipeline opens
    sequences through `pipeline.sequence.open_sequence`, which also fixes sensor, width and poses)."""
    return dataset_factory(detect_format(path) if fmt == "auto" else fmt, path, **opts)
