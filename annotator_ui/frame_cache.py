"""Frames the viewer has fetched, shared by all its tabs: payloads in a byte-bounded LRU and each
sequence's frame list (index -> id and pose). Frames never change once ingested, so sharing them
across operators is safe; a re-ingest gives new frame ids.
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
            self._payloads[frame_id] = value
            self._bytes += value.nbytes
            while self._bytes > self.max_bytes and len(self._payloads) > 1:
                _, old = self._payloads.popitem(last=False)
                self._bytes -= old.nbytes
        fut.set_result(value)
        return value

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
