"""Readers and writers of LiDAR formats, behind one Protocol and a registry.

Use `dataset_factory(name, path, **opts)` or `open_reader(path)` (auto-detects the format); the
pipeline opens sequences through `pipeline.sequence.open_sequence`.
"""

from __future__ import annotations

from pipeline.io.registry import dataset_factory, detect_format, frame_files, open_reader, register_reader

__all__ = ["dataset_factory", "detect_format", "frame_files", "open_reader", "register_reader"]
