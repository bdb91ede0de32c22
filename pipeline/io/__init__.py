"""Readers and writers of LiDAR formats, behind one Protocol and a registry.

Use `dataset_factory(name, path, **opts)` or `open_sequence(path)` (auto-detects the format).
"""

from __future__ import annotations

from pipeline.io.registry import dataset_factory, detect_format, open_sequence, register_reader

__all__ = ["dataset_factory", "detect_format", "open_sequence", "register_reader"]
