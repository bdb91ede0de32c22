"""What keeps a key's path short (issue 37): the next track fetched before the key (a fake
service records the order of the calls), the background cloud's level of detail that never thins
the reviewed track, and colour-only updates while the same frame stays on screen."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from annotator_ui.client import ApiClient, FramePayload
from annotator_ui.cloud_lod import lod
from annotator_ui.frame_cache import FrameCache
from annotator_ui.headless import HeadlessClient, is_points
from annotator_ui.prefetch import prefetch_next
from annotator_ui.review import QueueCoordinator, ReviewSession
from annotator_ui.viewer import AnnotatorViewer, ViewerConfig
from tests.annotator_ui.test_viewer import wait_until


def _detail(track_id: int, frame_index: int) -> dict:
    seg = {"frame_id": 100 + frame_index, "frame_index": frame_index, "n_points": 10, "in_kept_range": True,
           "centroid_world": [1.0, 2.0, 0.0], "centroid": [1.0, 2.0, 0.0]}
    return {"id": track_id, "version": 1, "status": "pending", "sequence_id": 1, "first_frame": frame_index,
            "last_frame": frame_index, "keep_start": frame_index, "keep_end": frame_index, "n_points": 10,
            "mean_range": 5.0, "segments": [seg]}


class FakeService:
    """The review queue as the service runs it (a user's own live lease first, else the first
    free pending track), recording every call the viewer makes."""

    token = "operator"

    def __init__(self, n_tracks: int = 4) -> None:
        self.tracks = {i: _detail(i, frame_index=i) for i in range(1, n_tracks + 1)}
        self.leased: set[int] = set()
        self.calls: list[tuple] = []

    def next_track(self, exclude=(), sequence_id=None):
        self.calls.append(("next", tuple(sorted(exclude))))
        pending = [i for i, t in self.tracks.items() if t["status"] == "pending" and i not in set(exclude)]
        own = [i for i in pending if i in self.leased]
        free = own or [i for i in pending if i not in self.leased]
        if not free:
            return None
        self.leased.add(free[0])
        return {k: v for k, v in self.tracks[free[0]].items() if k != "segments"}

    def track(self, track_id: int) -> dict:
        self.calls.append(("track", track_id))
        return copy.deepcopy(self.tracks[track_id])

    def act(self, track_id: int, action: str, version: int, **_body) -> dict:
        self.calls.append(("act", track_id, action))
        t = self.tracks[track_id]
        t["status"], t["version"] = "accepted", version + 1
        self.leased.discard(track_id)
        return copy.deepcopy(t)

    def frames(self, sequence_id: int) -> list[dict]:
        self.calls.append(("frames", sequence_id))
        return [{"id": 100 + i, "index": i, "pose": None} for i in range(10)]

    def frame_payload(self, frame_id: int) -> FramePayload:
        self.calls.append(("payload", frame_id))
        n = 5
        return FramePayload(np.zeros((n, 3), np.float32), np.zeros(n, np.float32), np.zeros(n, np.int32),
                            np.full(n, frame_id - 100, np.int64), etag=f"e{frame_id}")

    def release(self, track_id: int) -> None:
        self.calls.append(("release", track_id))
        self.leased.discard(track_id)


def _calls_since(service: FakeService, mark: int, kind: str) -> list[tuple]:
    return [c for c in service.calls[mark:] if c[0] == kind]


def test_prefetch_fetches_the_next_track_and_its_frame_before_the_key():
    service = FakeService()
    session, cache, prepared = ReviewSession(service), FrameCache(), []  # type: ignore[arg-type]
    session.next()
    assert session.track_id == 1
    assert prefetch_next(session, service, cache, lambda fid, p: prepared.append(fid)) == 2  # type: ignore[arg-type]
    assert ("track", 2) in service.calls and ("payload", 102) in service.calls and prepared == [102]
    key = len(service.calls)
    session.accept()  # the key
    assert session.track_id == 2
    assert _calls_since(service, key, "act") == [("act", 1, "accept")]
    assert _calls_since(service, key, "track") == []  # the detail read ahead is shown as it is
    cache.payload(service, 102)  # type: ignore[arg-type]  # what the draw asks for
    assert _calls_since(service, key, "payload") == []


def test_prefetch_rereads_a_track_changed_since_it_was_read_ahead():
    service = FakeService()
    session = ReviewSession(service)  # type: ignore[arg-type]
    session.next()
    prefetch_next(session, service, FrameCache(), lambda *_: None)  # type: ignore[arg-type]
    service.tracks[2]["version"] = 5  # another tab edited it meanwhile
    key = len(service.calls)
    session.accept()
    assert session.track_id == 2 and session.track["version"] == 5
    assert _calls_since(service, key, "track") == [("track", 2)]


def test_prefetch_track_ahead_is_passed_over_by_the_other_tabs_of_the_token():
    service, coordinator = FakeService(), QueueCoordinator()
    a = ReviewSession(service, coordinator)  # type: ignore[arg-type]
    b = ReviewSession(service, coordinator)  # type: ignore[arg-type]
    a.next()
    prefetch_next(a, service, FrameCache(), lambda *_: None)  # type: ignore[arg-type]
    b.next()  # the service would hand out the token's own lease on track 2 first
    assert (a.track_id, a.ahead_id, b.track_id) == (1, 2, 3)


def test_prefetch_ahead_lease_is_given_back_when_the_queue_changes():
    service = FakeService()
    session = ReviewSession(service)  # type: ignore[arg-type]
    session.next()
    prefetch_next(session, service, FrameCache(), lambda *_: None)  # type: ignore[arg-type]
    session.drop_ahead()
    assert ("release", 2) in service.calls and session.ahead_id is None and 2 not in session.leased


def test_prefetch_after_the_tab_closed_keeps_no_lease():
    service = FakeService()
    session = ReviewSession(service)  # type: ignore[arg-type]
    session.next()
    session.close()  # a prefetch still in flight when the tab closes
    assert prefetch_next(session, service, FrameCache(), lambda *_: None) is None  # type: ignore[arg-type]
    assert service.leased == set()


def test_lod_keeps_one_point_per_voxel_and_the_sparse_far_field():
    rng = np.random.default_rng(0)
    crowded = rng.uniform(0.0, 0.19, size=(50, 3)).astype(np.float32)  # one 0.2 m cube
    far = np.stack([np.arange(100) * 1.0 + 30.0, np.zeros(100), np.zeros(100)], axis=1).astype(np.float32)
    pts = np.concatenate([crowded, far, [[np.nan, 0.0, 0.0]]]).astype(np.float32)
    keep = lod(pts, budget=1000, voxel_m=0.2)
    assert keep.tolist() == [0, *range(50, 150)]  # the first crowded point, every far one, no NaN
    big = rng.uniform(-50, 50, size=(124_000, 3)).astype(np.float32)
    keep = lod(big, budget=24_576, voxel_m=0.2)
    assert len(keep) == 24_576 and np.all(np.diff(keep) > 0)


@pytest.fixture
def tiny_budget_tab(live_api):
    v = AnnotatorViewer(ViewerConfig(api_url=live_api.url, token=live_api.new_operator(), port=0, cloud_budget=16))
    c = HeadlessClient(v.url)
    c.wait_for(is_points("/frame/points"))
    wait_until(lambda: len(v.tabs) == 1 and v.tabs[0].session.track is not None)
    yield v.tabs[0], c
    c.close()
    v.stop()


def test_viewer_lod_thins_the_background_and_never_the_track(tiny_budget_tab, live_api):
    tab, client = tiny_budget_tab
    tid, fi = tab.session.track_id, tab.session.frame_index
    frame = next(s for s in tab.session.track["segments"] if s["frame_index"] == fi)
    payload = ApiClient(live_api.url, live_api.admin_token).frame_payload(frame["frame_id"])
    cloud = client.wait_for(is_points("/frame/points")).fields["props"]["points"]["nbytes"] // 12
    track = client.wait_for(is_points("/frame/track")).fields["props"]["points"]["nbytes"] // 12
    assert cloud == 16 < len(payload.points)
    assert track == int((payload.track == tid).sum()) > 16  # every point of the track, over the budget


def test_viewer_same_frame_sends_only_the_colours(tiny_budget_tab):
    tab, client = tiny_budget_tab
    since = client.mark()
    tab.scene.colour_mode = "class"  # recolours the same frame
    assert tab.render_frame()
    update = client.wait_for(lambda m: m.type == "SceneNodeUpdateMessage" and m.name == "/frame/points", since=since)
    assert set(update.fields["updates"]) == {"colors"} and update.fields["updates"]["colors"]["nbytes"] == 16 * 3
    assert not any(is_points("/frame/points")(m) for m in client.messages[since:])

