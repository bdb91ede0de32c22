"""The next track, fetched while the operator decides on the shown one.

After each track is drawn, the tab leases the queue's next track ahead (annotator_ui.review:
`read_ahead`), reads its detail, fetches the frame it will open at into the shared frame cache
and makes that frame's background cloud (its level of detail and colours). The key then posts
the action and the lease, and only draws: no track detail, no frame payload, no colouring on its
path. Tracks that open aggregated (far or sparse) have all their kept frames fetched.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from annotator_ui.client import ApiClient, ApiError, FramePayload
from annotator_ui.frame_cache import FrameCache
from annotator_ui.review import ReviewSession, best_frame
from annotator_ui.track_views_panel import hard_to_read


def prefetch_next(session: ReviewSession, api: ApiClient, cache: FrameCache,
                  prepare: Callable[[int, FramePayload], Any]) -> int | None:
    """Fetch the track after the shown one and its frames; `prepare(frame_id, payload)` makes the
    cloud of the frame it opens at. The track's id, or None when nothing is shown or left, or the
    service failed (the key then fetches as it would without a prefetch)."""
    if session.track is None:
        return None
    try:
        track = session.read_ahead()
        if track is None:
            return None
        frames = cache.frames(api, int(track["sequence_id"]))
        first = frames.get(best_frame(track))
        if first is not None:
            prepare(int(first["id"]), cache.payload(api, int(first["id"])))
        if hard_to_read(track):
            for seg in track["segments"]:
                frame = frames.get(int(seg["frame_index"]))
                if seg["in_kept_range"] and frame is not None:
                    cache.payload(api, int(frame["id"]))
    except ApiError:
        return None
    return int(track["id"])
