"""The change feed against a scripted service: what it tells a tab, and when."""

from __future__ import annotations

from typing import Any

from annotator_ui.change_feed import ChangeFeed
from annotator_ui.frame_cache import FrameCache


class _Api:
    """Answers `changes` from a script of region lists, one per poll."""

    def __init__(self, region_ids: list[list[int]]) -> None:
        self.region_ids = list(region_ids)

    def changes(self, sequence_id: int, since: str | None = None) -> dict[str, Any]:
        ids = self.region_ids.pop(0)
        return {"cursor": "c", "tracks": [], "frames": [], "truncated": False, "region_ids": ids}


class _Tab:
    def __init__(self, api: _Api, shown: tuple[int, ...] = ()) -> None:
        self.api, self.shown, self.refreshes = api, shown, 0

    def watched_sequence(self) -> int | None:
        return 1

    def service_changed(self, tracks: dict[int, dict[str, Any]], frames: dict[int, str]) -> None:
        pass

    def shown_regions(self) -> tuple[int, ...]:
        return self.shown

    def regions_changed(self) -> None:
        self.refreshes += 1


def test_feed_tells_a_tab_that_shows_a_region_drawn_and_undone_between_two_polls():
    tab = _Tab(_Api([[], []]))
    feed = ChangeFeed(FrameCache(), lambda: [tab])
    feed.poll_now(1)
    assert tab.refreshes == 0
    tab.shown = (7,)  # the tab read region 7 itself; it was undone before the next poll
    feed.poll_now(1)
    assert tab.refreshes == 1


def test_feed_leaves_a_tab_that_shows_the_live_regions_alone_and_spares_the_editing_tab():
    api = _Api([[3, 7], [3, 7], [3]])
    tab, editing = _Tab(api, (3, 7)), _Tab(api, (3, 7))
    feed = ChangeFeed(FrameCache(), lambda: [tab, editing])
    feed.poll_now(1)
    feed.poll_now(1)
    assert (tab.refreshes, editing.refreshes) == (0, 0)
    feed.poll_now(1, exclude=editing)
    assert (tab.refreshes, editing.refreshes) == (1, 0)
