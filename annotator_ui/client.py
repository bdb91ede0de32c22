"""The viewer's one way into the track service: a small httpx client of `/api/v1`.

Nothing else in `annotator_ui` speaks HTTP, and nothing here imports the service's code; the
shapes below mirror the service's public JSON (tracks, segments, jobs, progress) as plain dicts,
and the frame payload as a typed array bundle.

Errors: every non-2xx answer raises `ApiError` (status + the service's `detail`); a 409 raises its
subclass `StaleEdit`, which the viewer turns into a notification and a reload.
"""

from __future__ import annotations

import io
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import httpx
import numpy as np

API_PREFIX = "/api/v1"


class ApiError(Exception):
    """A non-2xx answer of the service: `status` and its `detail` message."""

    def __init__(self, status: int, detail: str, path: str = "") -> None:
        super().__init__(f"{status} {path}: {detail}" if path else f"{status}: {detail}")
        self.status = status
        self.detail = detail
        self.path = path


class StaleEdit(ApiError):
    """409: the track changed since the viewer read it (or there is nothing to undo)."""


class NothingToUndo(StaleEdit):
    """409 whose detail says there is no action left to undo (not a changed track)."""


def _conflict(status: int, detail: str, path: str) -> ApiError:
    cls = NothingToUndo if detail.startswith("nothing to undo") else StaleEdit
    return cls(status, detail, path)


@dataclass(frozen=True)
class FramePayload:
    """One frame as the viewer draws it (lidar frame, sensor-centred).

    points:    (N, 3) float32, metres in the lidar frame
    intensity: (N,) float32
    segment:   (N,) int32, -1 = ground / no segment
    track:     (N,) int64, database track id, 0 = no track
    etag:      the service's version of the frame (a split, merge or undo changes it)
    ground:    (N,) bool, the ground estimate (what a ground region labels); None = all False
    """

    points: np.ndarray
    intensity: np.ndarray
    segment: np.ndarray
    track: np.ndarray
    etag: str = ""
    ground: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = len(self.points)
        assert self.points.shape == (n, 3) and self.points.dtype == np.float32, self.points.shape
        assert self.intensity.shape == (n,) and self.segment.shape == (n,) and self.track.shape == (n,)
        if self.ground is None:
            object.__setattr__(self, "ground", np.zeros(n, bool))
        assert self.ground is not None and self.ground.shape == (n,) and self.ground.dtype == np.bool_

    @property
    def nbytes(self) -> int:
        assert self.ground is not None
        return int(self.points.nbytes + self.intensity.nbytes + self.segment.nbytes + self.track.nbytes
                   + self.ground.nbytes)

    @classmethod
    def from_npz(cls, body: bytes, etag: str = "") -> FramePayload:
        """Parse the service's `/frames/{id}/payload` body (an uncompressed .npz)."""
        with np.load(io.BytesIO(body)) as z:
            return cls(
                etag=etag,
                points=np.ascontiguousarray(z["points"], dtype=np.float32),
                intensity=np.ascontiguousarray(z["intensity"], dtype=np.float32),
                segment=np.ascontiguousarray(z["segment"], dtype=np.int32),
                track=np.ascontiguousarray(z["track"], dtype=np.int64),
                ground=np.ascontiguousarray(z["ground"], dtype=bool) if "ground" in z.files else None,
            )


def _detail(response: httpx.Response) -> str:
    try:
        body = response.json()
    except ValueError:
        return response.text[:500] or response.reason_phrase
    detail = body.get("detail", body) if isinstance(body, dict) else body
    if isinstance(detail, list):  # FastAPI validation errors
        return "; ".join(f"{'.'.join(str(p) for p in e.get('loc', []))}: {e.get('msg')}" for e in detail)
    return str(detail)


class ApiClient:
    """A bearer-token client of one track service. Thread-safe (httpx pools connections)."""

    def __init__(self, base_url: str, token: str | None, timeout: float = 30.0,
                 transport: httpx.BaseTransport | None = None):
        """`token` None: no Authorization header (enough for /health)."""
        base = base_url.rstrip("/")
        if base.endswith(API_PREFIX):
            base = base[: -len(API_PREFIX)]
        self.base_url = base
        self.token = token or ""
        self._paths: dict[str, Any] | None = None  # the OpenAPI paths, read on first use
        self._http = httpx.Client(
            base_url=base + API_PREFIX,
            headers={"Authorization": f"Bearer {token}"} if token else {},
            timeout=timeout,
            transport=transport,
        )

    def close(self) -> None:
        self._http.close()

    def __enter__(self) -> ApiClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ plumbing
    def _request(self, method: str, path: str, **kw: Any) -> httpx.Response:
        try:
            r = self._http.request(method, path, **kw)
        except httpx.HTTPError as exc:
            raise ApiError(0, f"cannot reach the track service at {self.base_url}: {exc}", path) from exc
        if r.status_code >= 400:
            if r.status_code == 409:
                raise _conflict(r.status_code, _detail(r), path)
            raise ApiError(r.status_code, _detail(r), path)
        return r

    def _json(self, method: str, path: str, **kw: Any) -> Any:
        return self._request(method, path, **kw).json()

    # ------------------------------------------------------------------ identity
    def health(self) -> dict[str, Any]:
        return self._json("GET", "/health")

    def me(self) -> dict[str, Any]:
        """The user behind the token (401 -> ApiError)."""
        return self._json("GET", "/users/me")

    # ------------------------------------------------------------------ review queue
    def next_track(self, exclude: Iterable[int] = (), sequence_id: int | None = None) -> dict[str, Any] | None:
        """Lease the next pending track (TrackPublic), or None when nothing is left."""
        params: dict[str, Any] = {}
        ex = sorted({int(t) for t in exclude})
        if ex:
            params["exclude"] = ex
        if sequence_id is not None:
            params["sequence_id"] = sequence_id
        r = self._request("POST", "/review/next", params=params)
        return None if r.status_code == 204 else r.json()

    def lease(self, track_id: int) -> dict[str, Any]:
        """Lease a chosen track (TrackPublic); StaleEdit (409) while another operator holds it."""
        return self._json("POST", f"/review/{track_id}/lease")

    def release(self, track_id: int) -> None:
        self._request("POST", f"/review/{track_id}/release")

    # ------------------------------------------------------------------ tracks
    def track(self, track_id: int) -> dict[str, Any]:
        """TrackDetail: the track with its `segments` (frame_id, frame_index, centroid_world, ...)."""
        return self._json("GET", f"/tracks/{track_id}")

    def tracks_by_id(self, ids: Iterable[int]) -> dict[int, dict[str, Any]]:
        """TrackPublic of each id that exists, keyed by id (chunks of 500)."""
        wanted = sorted({int(i) for i in ids if int(i) > 0})
        out: dict[int, dict[str, Any]] = {}
        for i in range(0, len(wanted), 500):
            chunk = wanted[i : i + 500]
            body = self._json("GET", "/tracks", params={"ids": chunk, "limit": 500})
            out.update({t["id"]: t for t in body["items"]})
        return out

    def list_tracks(self, **params: Any) -> dict[str, Any]:
        return self._json("GET", "/tracks", params=params)

    def events(self, track_id: int) -> list[dict[str, Any]]:
        return self._json("GET", f"/tracks/{track_id}/events")

    def act(self, track_id: int, action: str, version: int, **body: Any) -> dict[str, Any]:
        """A review action of the service (`crud.REVIEW_ACTIONS`: accept, discard, label(label=),
        truncate(start=, end=), undo, ...); returns TrackPublic. A stale `version` raises StaleEdit;
        an action the service does not have answers 404 (ApiError)."""
        if not action.isidentifier():
            raise ValueError(f"not an action name: {action!r}")
        return self._json("POST", f"/tracks/{track_id}/{action}", json={"version": version, **body})

    def split(self, track_id: int, version: int, region: dict[str, Any], frame_index: int | None = None) -> dict[str, Any]:
        """Cut the track's points inside `region` (world frame; see the service's SplitAction)
        out into a new track, in every kept frame or in `frame_index` only. Returns SplitPublic:
        `track`, `new_track`, `moved_points`. A region selecting nothing or everything -> ApiError 422."""
        body: dict[str, Any] = {"version": version, "region": region}
        if frame_index is not None:
            body["frame_index"] = frame_index
        return self._json("POST", f"/tracks/{track_id}/split", json=body)

    def merge(self, track_id: int, version: int, other_id: int, other_version: int) -> dict[str, Any]:
        """Join track `other_id` into `track_id`; returns the joined TrackPublic."""
        return self._json("POST", f"/tracks/{track_id}/merge",
                          json={"version": version, "other_track_id": other_id, "other_version": other_version})

    def sample_png(self, sample_url: str) -> bytes:
        """The PNG of a segment's sample (`sample_url` as the track detail gives it)."""
        path = sample_url.removeprefix(API_PREFIX)
        return self._request("GET", path).content

    # ------------------------------------------------------------------ frames
    def frames(self, sequence_id: int) -> list[dict[str, Any]]:
        """Every frame of a sequence (FramePublic: id, index, pose = T_world_lidar row-major)."""
        items: list[dict[str, Any]] = []
        while True:
            body = self._json(
                "GET", f"/sequences/{sequence_id}/frames", params={"limit": 10_000, "offset": len(items)}
            )
            items.extend(body["items"])
            if not body["items"] or len(items) >= body["total"]:
                return items

    def frame_payload(self, frame_id: int) -> FramePayload:
        r = self._request("GET", f"/frames/{frame_id}/payload")
        return FramePayload.from_npz(r.content, r.headers.get("etag", ""))

    def changes(self, sequence_id: int, since: str | None = None) -> dict[str, Any]:
        """SequenceChanges: `cursor` (pass back as `since`), changed `tracks` (id, version, status,
        n_points), the `frames` (id, index, etag) they have points in, and `region_ids`, the ids of
        the sequence's live ground regions."""
        return self._json("GET", f"/sequences/{sequence_id}/changes", params={} if since is None else {"since": since})

    def points_progress(self, sequence_id: int) -> dict[str, Any]:
        """PointsProgress: points, points_in_tracks, points_labelled(_per_source), ..."""
        return self._json("GET", f"/sequences/{sequence_id}/points-progress")

    def sequences(self) -> list[dict[str, Any]]:
        return self._json("GET", "/sequences")

    def label_set(self, sequence_id: int) -> dict[str, Any]:
        """LabelSetPublic: the sequence's classes (name, colour, key, ground, ...) in index order."""
        return self._json("GET", f"/sequences/{sequence_id}/label-set")

    # ------------------------------------------------------------------ progress and jobs
    def stats(self, sequence_id: int | None = None) -> dict[str, Any]:
        """ProgressStats: tracks_by_status, tracks_reviewed, samples_labelled_per_class, ..."""
        params = {} if sequence_id is None else {"sequence_id": sequence_id}
        return self._json("GET", "/exports/stats", params=params)

    def job_types(self) -> list[dict[str, Any]]:
        return self._json("GET", "/job-types")

    def create_job(self, job_type: str, params: dict[str, Any] | None = None) -> dict[str, Any]:
        return self._json("POST", "/jobs", json={"type": job_type, "params": params or {}})

    def job(self, job_id: int) -> dict[str, Any]:
        return self._json("GET", f"/jobs/{job_id}")

    def jobs(self, limit: int = 20) -> list[dict[str, Any]]:
        return self._json("GET", "/jobs", params={"limit": limit})

    def cancel_job(self, job_id: int) -> dict[str, Any]:
        return self._json("POST", f"/jobs/{job_id}/cancel")

    # ------------------------------------------------------------------ optional routes
    def has_route(self, method: str, path: str) -> bool:
        """Whether the service's OpenAPI schema lists `method path` (e.g. routes later issues add).
        The schema is read once per client: panels ask after every action, and it is ~100 kB."""
        if self._paths is None:
            try:
                self._paths = self._json("GET", "/openapi.json").get("paths", {})
            except ApiError:
                return False
        return method.lower() in self._paths.get(API_PREFIX + path, {})

    def get(self, path: str, **params: Any) -> Any:
        """GET any JSON route under /api/v1 (for panels of optional features)."""
        return self._json("GET", path, params=params)

    def post(self, path: str, body: dict[str, Any] | None = None) -> Any:
        return self._json("POST", path, json=body or {})

    # ------------------------------------------------------------------ ground regions
    def ground_regions(self, sequence_id: int) -> list[dict[str, Any]]:
        """GroundRegionPublic of the sequence (id, class_name, polygon [[x, y], ...] world), oldest first."""
        return self._json("GET", f"/sequences/{sequence_id}/ground-regions")

    def create_ground_region(self, sequence_id: int, class_name: str, polygon: list[list[float]],
                             heights: tuple[float, float] | None = None, frame_index: int | None = None,
                             clip_from_world: np.ndarray | None = None) -> dict[str, Any]:
        """Label the ground points inside `polygon` (world x, y; 3..1000 vertices) as `class_name` in
        every frame, or with `heights` (world z low, high) every point inside the prism; with
        `frame_index` in that frame only, and with `clip_from_world` ((4, 4) of the camera) every
        point of that frame inside `polygon` drawn in its device coordinates; 422 (ApiError) for
        a class outside the sequence's label set, no area, heights out of order or no such frame."""
        body: dict[str, Any] = {"class_name": class_name, "polygon": polygon}
        if heights is not None:
            body["z_min"], body["z_max"] = float(heights[0]), float(heights[1])
        if frame_index is not None:
            body["frame_index"] = int(frame_index)
        if clip_from_world is not None:
            body["clip_from_world"] = np.asarray(clip_from_world, np.float64).reshape(-1).tolist()
        return self._json("POST", f"/sequences/{sequence_id}/ground-regions", json=body)

    def delete_ground_region(self, region_id: int) -> dict[str, Any]:
        """Undo a ground region (404 when it is gone already)."""
        return self._json("DELETE", f"/ground-regions/{region_id}")
