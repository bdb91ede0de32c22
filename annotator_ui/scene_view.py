"""What a tab draws in its 3D view: the shown frame's points, the track in its real colours with
its outline, the aggregated cloud, the path over the route, and the camera aimed at the track.

Scene (the current frame's lidar frame, sensor at the origin, z up, points in float32):
  /frame/points   every point of the frame, coloured by the colour mode, faded around the track;
                  the ground points that stored ground regions label in their class colours
  /frame/track    the reviewed track's points in this frame in their real colours (height or
                  intensity; grey outside the kept range)
  /frame/outline  a box around them (the halo that finds the track without hiding its shape)
  /track/aggregate  the points of all kept frames overlaid (while "Aggregate" is ticked)
  /track/path     the track's centroids over its frames (world centroids moved into this frame)
  /track/nodes    those centroids, small; orange inside the kept range, grey outside, white = this frame

The background cloud is faded as a whole (the track is drawn on top of it in its own colours), so
in the *track* colour mode it does not depend on which track is reviewed. Its points are the
frame's level of detail (annotator_ui.cloud_lod), sent as binary once per frame; while the same
frame stays on screen only what changed is sent: nothing for the next track in that frame, the
colour array alone after an edit rewrote the frame's tracks or when another colour mode (or a
review, in the class and status modes) recolours it. The points of a frame never change.

`shown` is what the client has applied (track id, version, frame id, frame ETag): a key is bound
to it. A draw becomes `shown` when the client answers a request sent in the same atomic update
(a localStorage read: the client applies a batch's messages in order, so its answer leaves after
the draw is applied and before any key pressed on it); a key that arrives before the answer was
pressed on the previous track. viser's own `get_item` sends the same message, but from another
thread and in a later batch, one animation frame later.
"""

from __future__ import annotations

import secrets
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import viser
from viser import _messages as viser_messages

from annotator_ui.client import ApiClient, ApiError, FramePayload
from annotator_ui.cloud_lod import MAX_CLOUD_POINTS, VOXEL_M, CloudMemo, lod
from annotator_ui.colours import ColourMode, fade, point_colours
from annotator_ui.frame_cache import FrameCache
from annotator_ui.geometry import polyline_segments, pose_matrix, world_to_lidar
from annotator_ui.label_set import PAPER
from annotator_ui.review import ReviewSession
from annotator_ui.track_look import OUTLINE, aggregate, box_outline, track_colours
from annotator_ui.track_views_panel import TrackViewsPanel, frame_cuts

POINT_SIZE = 0.06
TRACK_POINT_SIZE = 0.08  # a little larger than the rest: dense enough to read the shape, never a blob
NODE_SIZE = 0.12  # path markers small enough not to cover a pedestrian
OUTSIDE_KEPT = (150, 150, 150)
PATH_KEPT = (255, 140, 0)
# the side panels (sample, route, stitches) follow a draw by this long after the client applied it:
# their images and rows then reach the browser after the track is drawn, not while it draws it
SIDE_PANELS_DELAY_S = 0.3
TRACK_NODES = ("/frame/track", "/frame/outline", "/track/aggregate", "/track/path", "/track/nodes")


@dataclass(frozen=True)
class Shown:
    """What the client was last sent."""

    track_id: int
    version: int
    frame_id: int
    etag: str


class SceneView:
    def __init__(self, client: viser.ClientHandle, api: ApiClient, cache: FrameCache, session: ReviewSession,
                 views: TrackViewsPanel, notify: Callable[[str, str, str], None], budget: int = MAX_CLOUD_POINTS,
                 voxel_m: float = VOXEL_M, side_panels_delay_s: float | None = SIDE_PANELS_DELAY_S) -> None:
        self.client, self.api, self.cache, self.session, self.views, self.notify = client, api, cache, session, views, notify
        self.budget, self.voxel_m, self.side_panels_delay_s = budget, voxel_m, side_panels_delay_s
        self.memo = CloudMemo()
        self.colour_mode: ColourMode = "track"
        self.table = PAPER  # the classes (colours) of the shown track's sequence
        self.follow_camera = True
        self.lock = threading.Lock()
        self.generation = 0  # bumped per frame drawn (a late sample load checks it)
        self.frame_points: np.ndarray | None = None  # (N, 3) float32 points of the frame shown
        self.frame_tracks: np.ndarray | None = None  # (N,) track id per point
        self.frame_ground: np.ndarray | None = None  # (N,) bool ground estimate per point
        self.frame_pose: np.ndarray = np.eye(4)  # T_world_lidar of the frame shown
        self.frame_sequence: int | None = None
        self.frame_index: int | None = None  # the shown frame's index in its sequence
        # the ground regions' colours over the background (GroundPanel.paint), None = none
        self.paint_ground: Callable[..., np.ndarray] | None = None
        self.shown: Shown | None = None
        self._sent: Shown | None = None
        self._cloud: viser.PointCloudHandle | None = None  # the background cloud on the client
        self._cloud_frame: int | None = None  # its frame id
        self._cloud_keep: np.ndarray | None = None  # (M,) its points' indices into the frame
        self._cloud_colours: np.ndarray | None = None  # (M, 3) uint8, as the client holds them
        self._receipts: dict[str, Shown] = {}  # request uuid -> the draw it follows
        self._after: list[Callable[[], None]] = []  # to run once the client applied the last draw
        self._after_lock = threading.Lock()
        self.timings_ms: dict[str, float] = {}
        self._conn = client._websock_connection  # noqa: SLF001 - see the module docstring
        self._conn.register_handler(viser_messages.LocalStorageGetItemResponseMessage, self._on_receipt)

    def close(self) -> None:
        self._conn.unregister_handler(viser_messages.LocalStorageGetItemResponseMessage, self._on_receipt)

    def _ask_receipt(self, sent: Shown) -> None:
        uuid = secrets.token_hex(8)
        self._receipts[uuid] = sent
        self._conn.queue_message(viser_messages.LocalStorageGetItemRequestMessage(key="tracklabel", request_uuid=uuid))

    def _on_receipt(self, _client_id: int, message: viser_messages.LocalStorageGetItemResponseMessage) -> None:
        """The client applied a draw (runs in viser's event loop, in order with the keys)."""
        sent = self._receipts.pop(message.request_uuid, None)
        if sent is not None and sent is self._sent:
            self.shown = sent
            self._run_after()

    def after_shown(self, fn: Callable[[], None]) -> None:
        """Run `fn` (nothing a key waits for) SIDE_PANELS_DELAY_S after the client applied the last
        draw; at once when nothing is drawn or side_panels_delay_s is None."""
        with self._after_lock:
            self._after.append(fn)
        if self._sent is None or self.shown is self._sent or self.side_panels_delay_s is None:
            self._run_after()

    def _run_after(self) -> None:
        with self._after_lock:
            fns, self._after = self._after, []
        if fns:
            timer = threading.Timer(self.side_panels_delay_s or 0.0, lambda: [fn() for fn in fns])
            timer.daemon = True
            timer.start()

    @property
    def sent(self) -> Shown | None:
        """What the client was last sent (it may not have applied it yet)."""
        return self._sent

    def clear(self) -> None:
        self.shown = self._sent = None
        self._cloud_frame = None
        for name in TRACK_NODES:
            self.client.scene.remove_by_name(name)

    def render(self, texts: Callable[[], None], reset_camera: bool = False) -> bool:
        """Draw the session's current frame and send it; `texts` updates the GUI in the same
        atomic update. False when the frame could not be read (nothing on the canvas changed)."""
        with self.lock:
            t0 = time.perf_counter()
            t, fi = self.session.track, self.session.frame_index
            if t is None or fi is None:
                return False
            try:
                frame = self.cache.frames(self.api, int(t["sequence_id"])).get(fi)
                if frame is None:
                    self.notify("Frame missing", f"frame {fi} of sequence {t['sequence_id']} is not in the service", "red")
                    return False
                payload = self.cache.payload(self.api, int(frame["id"]))
                t_fetched = time.perf_counter()
                info = None
                if self.colour_mode != "track":
                    info = self.api.tracks_by_id(np.unique(payload.track[payload.track > 0]).tolist())
                aggregated = self._aggregated(t, frame) if self.views.aggregated else None
            except ApiError as exc:
                self.notify("Cannot load the frame", exc.detail, "red")
                return False
            mask = payload.track == int(t["id"])
            if self.colour_mode == "track":  # the same for every track: the prefetch may have made it
                keep, colours = self.prepare_cloud(int(frame["id"]), payload)
            else:  # other modes follow the reviews
                keep, colours = self._background(payload, self.colour_mode, info)
            # what the canvas shows is known before the client sees it (a click or a cut may
            # arrive as soon as the cloud does)
            self.frame_points, self.frame_tracks = payload.points, payload.track
            self.frame_ground, self.frame_pose = payload.ground, pose_matrix(frame.get("pose"))
            self.frame_sequence, self.frame_index = int(t["sequence_id"]), int(fi)
            if self.paint_ground is not None:
                colours = self.paint_ground(colours, payload, keep, info, fi)
            t_coloured = time.perf_counter()
            self.generation += 1
            with self.client.atomic():
                self._draw_cloud(int(frame["id"]), payload, keep, colours)
                self._draw_track(t, fi, payload, mask, aggregated)
                self._draw_path(t, fi, pose_matrix(frame.get("pose")))
                texts()
                if reset_camera and self.follow_camera:
                    self._aim_camera(t, fi, payload.points[mask])
                self._sent = Shown(int(t["id"]), int(t["version"]), int(frame["id"]), payload.etag)
                self._ask_receipt(self._sent)
            self.client.flush()
            t_sent = time.perf_counter()
            self.timings_ms.update(frame_fetch=1e3 * (t_fetched - t0), colour=1e3 * (t_coloured - t_fetched),
                                   send=1e3 * (t_sent - t_coloured))
            return True

    def prepare_cloud(self, frame_id: int, payload: FramePayload) -> tuple[np.ndarray, np.ndarray]:
        """(M,) indices and (M, 3) uint8 colours of a frame's background cloud in the track colour
        mode, made once per frame version (the prefetch calls this for the next track's frame)."""
        return self.memo.get((frame_id, payload.etag, "track"), lambda: self._background(payload, "track", None))

    def _background(self, payload: FramePayload, mode: ColourMode,
                    info: dict[int, dict[str, Any]] | None) -> tuple[np.ndarray, np.ndarray]:
        keep = lod(payload.points, self.budget, self.voxel_m)
        colours = point_colours(payload.segment[keep], payload.track[keep], mode, info, self.table)
        return keep, fade(colours, np.zeros(len(keep), bool))

    def _draw_cloud(self, frame_id: int, payload: FramePayload, keep: np.ndarray, colours: np.ndarray) -> None:
        """Send the background cloud: whole when the client holds another frame's, else only its
        colours, and only when they changed."""
        same_points = (self._cloud is not None and self._cloud_frame == frame_id and self._cloud_keep is not None
                       and np.array_equal(self._cloud_keep, keep))
        if not same_points:
            self._cloud = self.client.scene.add_point_cloud("/frame/points", payload.points[keep], colours,
                                                            point_size=POINT_SIZE, precision="float32",
                                                            point_shading="flat")
            self._cloud_frame, self._cloud_keep = frame_id, keep
        elif not np.array_equal(self._cloud_colours, colours):
            self._cloud.colors = colours  # type: ignore[union-attr]  # the delta: one uint8 array
        self._cloud_colours = colours

    def drawn_points(self, track_id: int) -> int:
        """How many points of `track_id` the shown frame has (what the canvas draws)."""
        return 0 if self.frame_tracks is None else int((self.frame_tracks == track_id).sum())

    def _aggregated(self, t: dict[str, Any], frame: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
        """The kept frames' track points overlaid, in this frame's scene: (M, 3) points, (M,) intensity."""
        frames = self.cache.frames(self.api, int(t["sequence_id"]))
        cuts = frame_cuts(t, frames, lambda fid: self.cache.payload(self.api, fid))
        seg = self.session.segment_at(int(frame["index"]))
        anchor = np.asarray(seg["centroid_world"], np.float64) if seg is not None else None
        pts_world, intensity = aggregate(cuts, self.views.compensated, anchor)
        return world_to_lidar(pts_world, pose_matrix(frame.get("pose"))), intensity

    def _draw_track(self, t: dict[str, Any], fi: int, payload: FramePayload, mask: np.ndarray,
                    aggregated: tuple[np.ndarray, np.ndarray] | None) -> None:
        """The track in its real colours with an outline box; the aggregated cloud when asked;
        the orthographic images of whichever of the two is shown."""
        scene = self.client.scene
        pts, intensity = payload.points[mask], payload.intensity[mask]
        kept = t["keep_start"] <= fi <= t["keep_end"]
        colours = track_colours(pts, intensity, self.views.look) if kept else np.full((len(pts), 3), OUTSIDE_KEPT, np.uint8)
        if len(pts):
            scene.add_point_cloud("/frame/track", pts, colours, point_size=TRACK_POINT_SIZE, precision="float32",
                                  point_shading="flat")
        else:
            scene.remove_by_name("/frame/track")
        if aggregated is not None and len(aggregated[0]):
            agg_colours = track_colours(aggregated[0], aggregated[1], self.views.look)
            scene.add_point_cloud("/track/aggregate", aggregated[0], agg_colours, point_size=POINT_SIZE,
                                  precision="float32", point_shading="flat")
            outlined, view_colours = aggregated[0], agg_colours
        else:
            scene.remove_by_name("/track/aggregate")
            outlined, view_colours = pts, colours
        if len(outlined):
            scene.add_line_segments("/frame/outline", box_outline(outlined), OUTLINE if kept else OUTSIDE_KEPT,
                                    thickness=2.0, thickness_units="screen")
        else:
            scene.remove_by_name("/frame/outline")
        self.views.show(outlined, view_colours)

    def _draw_path(self, t: dict[str, Any], fi: int, T_world_lidar: np.ndarray) -> None:
        segs = sorted(t["segments"], key=lambda s: s["frame_index"])
        path = world_to_lidar(np.array([s["centroid_world"] for s in segs], np.float64).reshape(-1, 3), T_world_lidar)
        node_colours = np.array(
            [(255, 255, 255) if s["frame_index"] == fi else (PATH_KEPT if s["in_kept_range"] else OUTSIDE_KEPT)
             for s in segs], np.uint8).reshape(-1, 3)
        scene = self.client.scene
        if len(path) >= 2:
            seg_colours = np.repeat(node_colours[1:, None, :], 2, axis=1)
            scene.add_line_segments("/track/path", polyline_segments(path), seg_colours, thickness=0.03)
        else:
            scene.remove_by_name("/track/path")
        if len(path):
            scene.add_point_cloud("/track/nodes", path, node_colours, point_size=NODE_SIZE, precision="float32",
                                  point_shape="circle", point_shading="flat")

    def _aim_camera(self, t: dict[str, Any], fi: int, pts: np.ndarray) -> None:
        """Look at the track from the sensor's side, far enough back to see all of it and its
        surroundings: distance grows with the object's extent."""
        seg = self.session.segment_at(fi)
        if len(pts):
            c = pts.mean(axis=0).astype(np.float64)
            extent = float(np.ptp(pts, axis=0).max())
        elif seg is not None:
            c, extent = np.asarray(seg["centroid"], np.float64), 2.0
        else:
            return
        dist = float(np.clip(2.0 * extent + 8.0, 10.0, 70.0))
        outward = c[:2] / max(float(np.linalg.norm(c[:2])), 1e-6)
        eye = np.array([c[0] - 0.8 * dist * outward[0], c[1] - 0.8 * dist * outward[1], c[2] + 0.6 * dist])
        self.client.camera.position = eye  # position first: viser shifts look_at along with it
        self.client.camera.look_at = c
