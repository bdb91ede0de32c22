"""Frames the viewer has fetched, shared by all its tabs: payloads in a byte-bounded LRU and each
sequence's frame list (index -> id and pose).

A payload is the frame as the service held it when read: a split, a merge or an undo rewrites a
frame (new points per track), and the service's change feed then gives the frame a new ETag.
`invalidate` takes those ETags; a cached payload whose ETag differs is dropped, and a fetch that
was in flight with the old one is not kept. Poses and frame ids never change once ingested.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from concurrent.futures import Future
from typing import Any

from annotator_ui.client import ApiClient, FramePayload


class FrameCache:
    """Thread-safe; concurrent requests for one frame share a single fetch."""

    def __init__(self, max_bytes: int = 256 * 2**20) -> None:
        self.max_bytes = max_bytes
        self._lock = threading.Lock()
        self._payloads: OrderedDict[int, FramePayload] = OrderedDict()
        self._bytes = 0
        self._inflight: dict[int, Future[FramePayload]] = {}
        self._etags: dict[int, str] = {}  # frame id -> the newest ETag the change feed named
        self._frames: dict[int, dict[int, dict[str, Any]]] = {}  # sequence id -> index -> FramePublic
        self.hits = 0
        self.misses = 0

    def payload(self, api: ApiClient, frame_id: int) -> FramePayload:
        with self._lock:
            hit = self._payloads.get(frame_id)
            if hit is not None:
                self._payloads.move_to_end(frame_id)
                self.hits += 1
                return hit
            fut = self._inflight.get(frame_id)
            owner = fut is None
            if owner:
                fut = self._inflight[frame_id] = Future()
                self.misses += 1
        assert fut is not None
        if not owner:
            return fut.result()
        try:
            value = api.frame_payload(frame_id)
        except BaseException as exc:
            with self._lock:
                self._inflight.pop(frame_id, None)
            fut.set_exception(exc)
            raise
        with self._lock:
            self._inflight.pop(frame_id, None)
            known = self._etags.get(frame_id)
            if known is None or not value.etag or value.etag == known:  # else: read before a repair landed
                self._store(frame_id, value)
        fut.set_result(value)
        return value

    def _store(self, frame_id: int, value: FramePayload) -> None:
        old = self._payloads.pop(frame_id, None)
        if old is not None:
            self._bytes -= old.nbytes
        self._payloads[frame_id] = value
        self._bytes += value.nbytes
        while self._bytes > self.max_bytes and len(self._payloads) > 1:
            _, dropped = self._payloads.popitem(last=False)
            self._bytes -= dropped.nbytes

    def invalidate(self, etags: dict[int, str]) -> set[int]:
        """Record the service's ETag of each frame id; drop the payloads it makes stale. Returns
        the ids of the frames whose cached payload was dropped."""
        dropped: set[int] = set()
        with self._lock:
            for fid, etag in etags.items():
                self._etags[fid] = etag
                hit = self._payloads.get(fid)
                if hit is not None and hit.etag != etag:
                    self._bytes -= hit.nbytes
                    del self._payloads[fid]
                    dropped.add(fid)
        return dropped

    def drop_all(self) -> None:
        with self._lock:
            self._payloads.clear()
            self._bytes = 0

    def frames(self, api: ApiClient, sequence_id: int) -> dict[int, dict[str, Any]]:
        """Frame index -> FramePublic of a sequence (fetched once)."""
        with self._lock:
            known = self._frames.get(sequence_id)
        if known is not None:
            return known
        by_index = {int(f["index"]): f for f in api.frames(sequence_id)}
        with self._lock:
            self._frames[sequence_id] = by_index
        return by_index

    @property
    def nbytes(self) -> int:
        return self._bytes
