"""The review workflow (annotator_ui.review) against a real track service: every action is checked
by reading the track back through the API."""

from __future__ import annotations

import httpx
import pytest

from annotator_ui.client import ApiClient, StaleEdit
from annotator_ui.review import NoChange, QueueCoordinator, ReviewSession


@pytest.fixture
def session(live_api):
    api = ApiClient(live_api.url, live_api.new_operator())
    s = ReviewSession(api)
    yield s
    s.close()
    api.close()


def _multi_frame(session: ReviewSession) -> None:
    """Skip until the shown track spans at least 3 frames."""
    for _ in range(50):
        lo, hi = session.frame_range()
        if hi - lo >= 2:
            return
        session.skip()
    pytest.fail("no multi-frame track in the queue")


def _kept_multi_frame(session: ReviewSession) -> tuple[int, int]:
    """Skip until the shown track keeps at least 3 frames (an earlier test may have left a track
    truncated in the shared service); its kept range."""
    for _ in range(50):
        kept = int(session.track["keep_start"]), int(session.track["keep_end"])
        if kept[1] - kept[0] >= 2:
            return kept
        session.skip()
    pytest.fail("no track keeping 3 frames in the queue")


def test_review_next_shows_a_leased_pending_track(session):
    track = session.next()
    assert track is not None and track["status"] == "pending" and track["segments"]
    lo, hi = session.frame_range()
    assert lo <= session.frame_index <= hi and session.from_queue


def test_review_accept_changes_the_track_and_loads_the_next(session, live_api):
    first = session.next()
    session.accept()
    assert live_api.track(first["id"])["status"] == "accepted"
    assert session.track_id not in (None, first["id"]) and session.track["status"] == "pending"


def test_review_discard_changes_the_track(session, live_api):
    first = session.next()
    session.discard()
    assert live_api.track(first["id"])["status"] == "discarded"


def test_review_label_accepts_with_the_class(session, live_api):
    first = session.next()
    session.label("car")
    t = live_api.track(first["id"])
    assert (t["status"], t["label"]) == ("accepted", "car")


def test_review_truncate_before_keeps_the_current_frame_onwards(session, live_api):
    session.next()
    lo, hi = _kept_multi_frame(session)
    session.set_frame(lo + 1)
    session.truncate_before()
    t = live_api.track(session.track_id)
    assert (t["keep_start"], t["keep_end"], t["status"]) == (lo + 1, hi, "pending")
    assert session.track["keep_start"] == lo + 1  # the session shows the truncated track
    session.undo()  # leave the shared service as found: a later test's cut must not meet this truncation


def test_review_truncate_after_keeps_up_to_the_current_frame(session, live_api):
    session.next()
    lo, hi = _kept_multi_frame(session)
    session.set_frame(hi - 1)
    session.truncate_after()
    t = live_api.track(session.track_id)
    assert (t["keep_start"], t["keep_end"]) == (lo, hi - 1)
    assert t["length"] == hi - lo  # the service recounted the kept frames
    session.undo()  # leave the shared service as found


def test_review_undo_reverts_the_last_action_and_shows_that_track(session, live_api):
    first = session.next()
    session.label("person")
    assert session.track_id != first["id"]
    session.undo()
    t = live_api.track(first["id"])
    assert (t["status"], t["label"]) == ("pending", None)
    assert session.track_id == first["id"] and session.track["version"] == t["version"]


def test_review_undo_of_a_truncation_restores_the_range(session, live_api):
    session.next()
    kept = _kept_multi_frame(session)
    session.set_frame(kept[0] + 1)  # inside the kept range, past its start: a real truncation
    session.truncate_before()
    session.undo()
    t = live_api.track(session.track_id)
    assert (t["keep_start"], t["keep_end"]) == kept


def test_review_undo_with_nothing_done_says_nothing_to_undo(session):
    """Z with nothing to undo is not a changed track (it used to say "Not saved: the track changed")."""
    session.next()
    with pytest.raises(NoChange, match="nothing to undo"):
        session.undo()


def test_review_truncate_on_the_kept_range_ends_sends_nothing(session, live_api):
    """] on the last kept frame (or [ on the first) would store an event that changes nothing."""
    session.next()
    _multi_frame(session)
    version = session.track["version"]
    session.set_frame(session.track["keep_end"])
    with pytest.raises(NoChange):
        session.truncate_after()
    session.set_frame(session.track["keep_start"])
    with pytest.raises(NoChange):
        session.truncate_before()
    assert live_api.track(session.track_id)["version"] == version


def test_review_stale_version_raises_and_reloads(session, live_api):
    track = session.next()
    lo, hi = session.frame_range()
    live_api.admin_act(track["id"], "truncate", version=track["version"], start=lo, end=hi)  # someone else edits it
    with pytest.raises(StaleEdit):
        session.accept()
    assert live_api.track(track["id"])["status"] == "pending"  # nothing overwritten
    assert session.track["version"] == track["version"] + 1  # reloaded
    session.accept()  # and now it goes through
    assert live_api.track(track["id"])["status"] == "accepted"


def test_review_open_picks_a_track_out_of_queue_order(session, live_api):
    queued = session.next()
    other = live_api.track(queued["id"] + 1)
    session.open(other["id"])
    assert session.track_id == other["id"] and not session.from_queue
    session.accept()
    assert live_api.track(other["id"])["status"] == "accepted"
    assert session.track_id == queued["id"]  # back to the track the queue leased


def test_review_two_operators_never_get_the_same_track(live_api):
    a = ReviewSession(ApiClient(live_api.url, live_api.new_operator()))
    b = ReviewSession(ApiClient(live_api.url, live_api.new_operator()))
    seen_a, seen_b = set(), set()
    a.next(), b.next()
    for _ in range(4):
        assert a.track_id != b.track_id  # at every moment
        seen_a.add(a.track_id), seen_b.add(b.track_id)
        a.accept(), b.discard()
    assert not seen_a & seen_b  # and over time: a reviewed track never comes back
    a.close(), b.close()


def test_review_two_tabs_of_one_token_never_get_the_same_track(live_api):
    token = live_api.new_operator()
    coord = QueueCoordinator()
    tabs = [ReviewSession(ApiClient(live_api.url, token), coord) for _ in range(3)]
    for tab in tabs:
        tab.next()
    assert len({t.track_id for t in tabs}) == 3
    tabs[0].accept()  # the next track of tab 0 is none of the others'
    assert len({t.track_id for t in tabs}) == 3
    for tab in tabs:
        tab.close()


def test_review_picked_track_is_leased_so_another_operator_gets_others(live_api):
    a = ReviewSession(ApiClient(live_api.url, live_api.new_operator()))
    b = ReviewSession(ApiClient(live_api.url, live_api.new_operator()))
    probe = ApiClient(live_api.url, live_api.new_operator())
    head = probe.next_track()["id"]  # the track the queue hands out next
    probe.release(head)
    a.open(head)  # a picks exactly that track out of queue order
    assert a.track_id == head and a.held_by is None
    b.next()
    assert b.track_id not in (None, head)  # without a's lease the queue would have given b `head`
    b.open(head)  # b may look at it, but is told who holds it
    assert b.track_id == head and b.held_by is not None
    a.close(), b.close(), probe.close()


def test_review_closing_a_tab_gives_back_the_leases_of_picked_and_queue_tracks(live_api):
    a = ReviewSession(ApiClient(live_api.url, live_api.new_operator()))
    queued = a.next()["id"]
    pending = httpx.get(f"{live_api.url}/api/v1/tracks", params={"status": "pending", "limit": 50},
                        headers={"Authorization": f"Bearer {live_api.admin_token}"}, timeout=30).json()["items"]
    picked = next(t["id"] for t in pending if t["id"] != queued)
    a.open(picked)
    assert a.held_by is None
    b = ApiClient(live_api.url, live_api.new_operator())
    with pytest.raises(StaleEdit):  # held by a while its tab is open
        b.lease(picked)
    a.close()
    for track_id in (picked, queued):  # free for another operator once the tab is gone
        assert b.lease(track_id)["id"] == track_id
        b.release(track_id)
    b.close()
