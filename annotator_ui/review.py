"""The review workflow of one operator's viewer tab, apart from any GUI: which track is shown,
which frame, what the actions send, and what undo reverts.

Rules:
  - accept, discard and a class (label = accept with that class) finish the track: the next one
    is leased from the queue at once;
  - truncate before / after the current frame edits the kept range and keeps the track open (the
    operator then labels or accepts it);
  - undo reverts the operator's last action of this tab (on whatever track it was), and shows
    that track again;
  - skip passes a track over for this tab (its lease is given back);
  - split cuts the shown track by a region (the new track is reviewed later, from the queue or
    by a click); merge joins another track into the shown one; undo reverts either;
  - a stale version (409) reloads the track and re-raises, so the GUI says so; nothing is retried
    silently; an action that would change nothing (truncating at the kept range's own end, undo
    with no action left) raises `NoChange` and sends nothing.

Several tabs of one user (one token) share the queue through a `QueueCoordinator`, which makes
each tab exclude the tracks the other tabs show, so no two tabs get the same track.

The track after the shown one is leased ahead (`lease_ahead`, while the operator decides): the
service hands a user's own live lease out first, so the key's `next` returns that same track,
and its detail read ahead is used when the version still matches. Other tabs of the token pass
it over like a shown track; closing the tab gives its lease back with the others.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from annotator_ui.client import ApiClient, NothingToUndo, StaleEdit

FINISHING = ("accept", "discard", "label")


def best_frame(track: dict[str, Any]) -> int:
    """The frame to open a track (TrackDetail) at: its kept segment with the most points."""
    kept = [s for s in track["segments"] if s["in_kept_range"]] or track["segments"]
    if not kept:
        return int(track["keep_start"])
    return int(max(kept, key=lambda s: (s["n_points"], -s["frame_index"]))["frame_index"])


class NoChange(Exception):
    """The action would change nothing; nothing was sent."""


@dataclass
class QueueCoordinator:
    """Hands out queue tracks to the tabs of one viewer process (shared by all its sessions)."""

    _lock: threading.Lock = field(default_factory=threading.Lock)
    _token_locks: dict[str, threading.Lock] = field(default_factory=dict)
    _sessions: dict[int, ReviewSession] = field(default_factory=dict)

    def register(self, session: ReviewSession) -> None:
        with self._lock:
            self._sessions[id(session)] = session
            self._token_locks.setdefault(session.api.token, threading.Lock())

    def unregister(self, session: ReviewSession) -> None:
        with self._lock:
            self._sessions.pop(id(session), None)

    def sessions(self) -> list[ReviewSession]:
        with self._lock:
            return list(self._sessions.values())

    def _token_lock(self, session: ReviewSession) -> threading.Lock:
        with self._lock:
            return self._token_locks.setdefault(session.api.token, threading.Lock())

    def _held(self, session: ReviewSession) -> set[int]:
        """The tracks the other tabs of `session`'s token show or hold ahead."""
        return {
            i
            for s in self.sessions()
            if s is not session and s.api.token == session.api.token
            for i in (s.track_id, s.ahead_id)
            if i is not None
        }

    def lease_next(self, session: ReviewSession) -> dict[str, Any] | None:
        """Lease the next track for `session`, passing over the tracks that the other tabs of the
        same token show and the ones this tab skipped. Serialised per process, so two tabs of one
        user cannot both receive the user's live lease."""
        with self._token_lock(session):  # one token's tabs take turns; other operators' tabs do not wait
            track = session.api.next_track(exclude=self._held(session) | session.skipped, sequence_id=session.sequence_id)
            session._set_queue_track(track)
            return track

    def lease_ahead(self, session: ReviewSession) -> dict[str, Any] | None:
        """Lease the track the queue gives `session` after the shown one (TrackPublic; None when
        nothing else is left), and mark it as `session`'s track ahead."""
        with self._token_lock(session):
            shown = session.track_id
            exclude = self._held(session) | session.skipped | ({shown} if shown is not None else set())
            track = session.api.next_track(exclude=exclude, sequence_id=session.sequence_id)
            with self._lock:
                closed = id(session) not in self._sessions
            if track is not None and closed:  # the tab closed meanwhile: its leases went back already
                session.api.release(int(track["id"]))
                return None
            if track is not None:
                session.leased.add(int(track["id"]))
                session.ahead_id = int(track["id"])  # other tabs pass it over from here on
            return track


class ReviewSession:
    """One tab's review state. Methods raise `ApiError` / `StaleEdit` for the GUI to show."""

    def __init__(self, api: ApiClient, coordinator: QueueCoordinator | None = None, sequence_id: int | None = None):
        self.api = api
        self.coordinator = coordinator or QueueCoordinator()
        self.sequence_id = sequence_id
        self.track: dict[str, Any] | None = None  # TrackDetail of the shown track
        self.frame_index: int | None = None
        self.from_queue = False  # shown because the queue leased it (not picked)
        self.history: list[int] = []  # track ids of this tab's actions, for undo
        self.skipped: set[int] = set()
        self.done = False  # the queue had nothing left
        self.held_by: str | None = None  # why the shown out-of-queue track could not be leased (None = leased)
        self.leased: set[int] = set()  # tracks this tab leased (queue and picked), given back on close
        self.ahead_id: int | None = None  # the queue's track after the shown one, leased ahead
        self.ahead: dict[str, Any] | None = None  # its TrackDetail, once read
        self.lock = threading.RLock()
        self.coordinator.register(self)

    def close(self) -> None:
        """Leave the coordinator and give back every lease this tab took (the queue's and those of
        picked tracks) that no other tab of the same user shows, so a closed tab does not keep
        other operators off its tracks until the leases run out."""
        self.coordinator.unregister(self)
        shown_elsewhere = {s.track_id for s in self.coordinator.sessions() if s.api.token == self.api.token}
        for track_id in sorted(self.leased - shown_elsewhere):
            try:
                self.api.release(track_id)
            except Exception:  # noqa: BLE001 - closing a tab never fails on a dead service
                pass
        self.leased.clear()

    # ------------------------------------------------------------------ what is shown
    @property
    def track_id(self) -> int | None:
        return None if self.track is None else int(self.track["id"])

    def segment_at(self, frame_index: int) -> dict[str, Any] | None:
        """The track's segment in frame `frame_index` (or None)."""
        if self.track is None:
            return None
        for seg in self.track["segments"]:
            if seg["frame_index"] == frame_index:
                return seg
        return None

    def frame_range(self) -> tuple[int, int]:
        assert self.track is not None
        return int(self.track["first_frame"]), int(self.track["last_frame"])

    def best_frame(self) -> int:
        """The frame to open the shown track at (`best_frame`)."""
        assert self.track is not None
        return best_frame(self.track)

    # ------------------------------------------------------------------ loading
    def _set_queue_track(self, track: dict[str, Any] | None) -> None:
        ahead, self.ahead, self.ahead_id = self.ahead, None, None
        if track is None:
            self.track, self.frame_index, self.from_queue, self.done = None, None, False, True
            return
        self.leased.add(int(track["id"]))
        if ahead is not None and (ahead["id"], ahead["version"]) == (track["id"], track["version"]):
            self._show(ahead, from_queue=True)  # read ahead, and unchanged since
        else:
            self._show(self.api.track(track["id"]), from_queue=True)

    def read_ahead(self) -> dict[str, Any] | None:
        """Lease the track after the shown one (if none is yet) and read its TrackDetail; None when
        the queue has nothing else. Runs beside the keys: a key that takes the track meanwhile
        reads it itself."""
        if self.ahead is not None:
            return self.ahead
        if self.ahead_id is None and self.coordinator.lease_ahead(self) is None:
            return None
        track_id = self.ahead_id
        if track_id is None:  # a key took it meanwhile
            return None
        detail = self.api.track(track_id)
        with self.lock:
            if self.ahead_id == track_id:
                self.ahead = detail
        return detail

    def drop_ahead(self) -> None:
        """Give back the track leased ahead (the queue changes, e.g. another sequence)."""
        with self.lock:
            track_id, self.ahead, self.ahead_id = self.ahead_id, None, None
        if track_id is not None:
            self.leased.discard(track_id)
            self.api.release(track_id)

    def _show(self, detail: dict[str, Any], from_queue: bool, frame_index: int | None = None) -> None:
        self.track = detail
        self.from_queue = from_queue
        self.done = False
        lo, hi = self.frame_range()
        if frame_index is None or not lo <= frame_index <= hi:
            frame_index = self.best_frame()
        self.frame_index = frame_index

    def next(self) -> dict[str, Any] | None:
        """Show the next track of the queue (None when nothing is left)."""
        with self.lock:
            self.coordinator.lease_next(self)
            return self.track

    def _lease(self, track_id: int) -> None:
        """Lease a track shown out of queue order, so the queue gives it to no one else; when
        another operator holds it, `held_by` says so (the version check still guards every edit)."""
        try:
            self.api.lease(track_id)
            self.held_by = None
            self.leased.add(int(track_id))
        except StaleEdit as exc:
            self.held_by = exc.detail

    def open(self, track_id: int, frame_index: int | None = None) -> dict[str, Any]:
        """Show any track out of queue order (picked in the scene), leased to this user while it is
        pending; the queue lease stays held."""
        with self.lock:
            self._lease(track_id)
            self._show(self.api.track(track_id), from_queue=False, frame_index=frame_index)
            assert self.track is not None
            return self.track

    def reload(self) -> dict[str, Any] | None:
        """Re-read the shown track (after a 409), keeping the frame."""
        with self.lock:
            if self.track is None:
                return None
            self._show(self.api.track(self.track["id"]), self.from_queue, self.frame_index)
            return self.track

    def set_frame(self, frame_index: int) -> int:
        lo, hi = self.frame_range()
        self.frame_index = int(min(max(frame_index, lo), hi))
        return self.frame_index

    # ------------------------------------------------------------------ actions
    def _edit(self, call: Callable[[], dict[str, Any]]) -> dict[str, Any]:
        """Run one edit of the shown track: a stale version reloads the track (the operator sees
        what changed) and raises; an edit that went through goes into this tab's undo history."""
        assert self.track is not None, "no track is shown"
        try:
            result = call()
        except StaleEdit:
            self.reload()
            raise
        self.history.append(int(self.track["id"]))
        return result

    def _act(self, action: str, **body: Any) -> dict[str, Any]:
        assert self.track is not None, "no track is shown"
        track = self.track
        return self._edit(lambda: self.api.act(track["id"], action, track["version"], **body))

    def finish(self, action: str, **body: Any) -> dict[str, Any]:
        """Any service action that settles the track (`POST /tracks/{id}/{action}`), then go on
        to the next: a new review action of the service needs no method here."""
        with self.lock:
            result = self._act(action, **body)
            self.coordinator.lease_next(self)
            return result

    def accept(self) -> dict[str, Any]:
        return self.finish("accept")

    def discard(self) -> dict[str, Any]:
        return self.finish("discard")

    def label(self, class_name: str) -> dict[str, Any]:
        """Give the track one class (the service accepts it too), then go on to the next."""
        return self.finish("label", label=class_name)

    def _truncate_at_current(self, keep: str) -> dict[str, Any]:
        """Keep `"after"` (current..keep_end) or `"before"` (keep_start..current) the current frame."""
        with self.lock:
            assert self.track is not None and self.frame_index is not None
            start, end = int(self.track["keep_start"]), int(self.track["keep_end"])
            if keep == "after":
                start = min(self.frame_index, end)
            else:
                end = max(self.frame_index, start)
            if (start, end) == (int(self.track["keep_start"]), int(self.track["keep_end"])):
                raise NoChange(f"frames {start}-{end} are already the kept range")
            result = self._act("truncate", start=start, end=end)
            self.reload()
            return result

    def truncate_before(self) -> dict[str, Any]:
        """Drop the frames before the current one: keep current..keep_end."""
        return self._truncate_at_current("after")

    def truncate_after(self) -> dict[str, Any]:
        """Drop the frames after the current one: keep keep_start..current."""
        return self._truncate_at_current("before")

    def undo(self) -> dict[str, Any]:
        """Revert this tab's last action and show that track. Nothing to undo -> StaleEdit."""
        with self.lock:
            if not self.history:
                raise NoChange("nothing to undo in this tab")
            track_id = self.history[-1]
            current = self.api.track(track_id)
            try:
                result = self.api.act(track_id, "undo", current["version"])
            except NothingToUndo:  # undone elsewhere (another tab of this operator)
                self.history.pop()
                raise
            self.history.pop()
            shown = self.track_id == track_id
            self._lease(track_id)  # pending again: keep the queue from handing it to someone else
            # a queue track shown until now stays leased to this user: the next `next` returns it
            self._show(self.api.track(track_id), from_queue=shown and self.from_queue,
                       frame_index=self.frame_index if shown else None)
            return result

    def split(self, region: dict[str, Any], this_frame_only: bool) -> dict[str, Any]:
        """Cut the shown track by `region` (world frame) in every kept frame or in the shown frame;
        the shown track stays (reloaded) and the cut-off track is pending in the queue."""
        with self.lock:
            assert self.track is not None
            frame = self.frame_index if this_frame_only else None
            track = self.track
            result = self._edit(lambda: self.api.split(int(track["id"]), int(track["version"]), region, frame))
            self.reload()
            return result

    def merge(self, other_id: int) -> dict[str, Any]:
        """Join track `other_id` into the shown track (its version read now, the shown track's as
        shown), then show the joined track."""
        with self.lock:
            assert self.track is not None
            if other_id == self.track_id:
                raise NoChange("a track cannot be merged with itself")
            other = self.api.track(other_id)
            track = self.track
            result = self._edit(
                lambda: self.api.merge(int(track["id"]), int(track["version"]), other_id, int(other["version"]))
            )
            self.reload()
            return result

    def skip(self) -> dict[str, Any] | None:
        """Pass the shown track over for this tab and show the next one."""
        with self.lock:
            if self.track is not None:
                self.skipped.add(int(self.track["id"]))
                if self.from_queue:
                    self.api.release(self.track["id"])
            self.coordinator.lease_next(self)
            return self.track
