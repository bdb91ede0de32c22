"""Keeps every open tab true to the service: one poller per viewer reads each shown sequence's
change feed (`GET /sequences/{id}/changes`), drops the cached frames a split, merge or undo
rewrote, and pushes the change to each tab that shows a changed track or a rewritten frame (the
tab re-reads its track and redraws). A tab's own edit polls at once (`poll_now`), so the tab
draws the new frames before the poller's next round; other tabs follow within `POLL_S`. Each answer
lists the sequence's live ground regions; a tab that shows other ones re-reads them. The feed
compares with what the tab shows, not with its previous answer: a tab reads regions itself (after
its own edit, on a new frame), so a region drawn and undone between two polls may be on screen
though the feed never listed it.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

from annotator_ui.client import ApiClient, ApiError
from annotator_ui.frame_cache import FrameCache

POLL_S = 1.0


class Watcher(Protocol):
    """A tab as the feed sees it."""

    api: ApiClient

    def watched_sequence(self) -> int | None: ...

    def service_changed(self, tracks: dict[int, dict[str, Any]], frames: dict[int, str]) -> None: ...

    def shown_regions(self) -> tuple[int, ...]: ...

    def regions_changed(self) -> None: ...


@dataclass
class _Cursor:
    since: str | None = None


class ChangeFeed:
    def __init__(self, cache: FrameCache, watchers: Callable[[], list[Watcher]], poll_s: float = POLL_S) -> None:
        self.cache = cache
        self.watchers = watchers
        self.poll_s = poll_s
        self._cursors: dict[int, _Cursor] = {}
        self._lock = threading.Lock()  # one poll of a sequence at a time, so cursors advance in order
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="annotator-changes", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()

    def _run(self) -> None:
        while not self._stop.wait(self.poll_s):
            for seq in sorted({s for w in self.watchers() if (s := w.watched_sequence()) is not None}):
                try:
                    self.poll_now(seq)
                except Exception:  # noqa: BLE001 - a dead service must not end the poller
                    pass

    def poll_now(self, sequence_id: int, exclude: Watcher | None = None) -> None:
        """Read the sequence's changes since the last poll, drop stale frames and tell the tabs
        (all but `exclude`, which is redrawing itself)."""
        watchers = [w for w in self.watchers() if w.watched_sequence() == sequence_id]
        if not watchers:
            return
        with self._lock:
            cursor = self._cursors.setdefault(sequence_id, _Cursor())
            try:
                feed = watchers[0].api.changes(sequence_id, cursor.since)
            except ApiError:
                return
            first = cursor.since is None
            cursor.since = feed["cursor"]
            regions = tuple(sorted(int(i) for i in feed.get("region_ids", [])))
            if not first:  # else the start of the feed: what the tabs read so far is current
                if feed.get("truncated"):
                    self.cache.drop_all()
                self.cache.invalidate({int(f["id"]): str(f["etag"]) for f in feed["frames"]})
        for w in watchers:  # the first answer too: a region drawn before it and after the tab read them is news
            if w is not exclude and w.shown_regions() != regions:
                w.regions_changed()
        if first:
            return
        frames = {int(f["id"]): str(f["etag"]) for f in feed["frames"]}
        tracks = {int(t["id"]): t for t in feed["tracks"]}
        if not tracks:
            return
        for w in watchers:  # each compares with what it drew: a repeat (the feed overlaps) changes nothing
            if w is not exclude:
                w.service_changed(tracks, frames)
