"""What the viewer caches, and the versions that tell it when to read again.

A track's version is its `version` column (every action bumps it). A frame's version is its
artifact file: a split, a merge or their undo points the frame at another file
(`<index>.<revision>.npz`) and nothing else changes a frame's points, so the file's name is the
frame's ETag.
"""

from __future__ import annotations

import hashlib


def frame_etag(artifact: str) -> str:
    """The strong ETag (quoted) of a frame whose artifact file is `artifact`."""
    return '"' + hashlib.sha1(artifact.encode()).hexdigest()[:16] + '"'
