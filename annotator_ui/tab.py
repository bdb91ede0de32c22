"""One browser tab: its review session, the panels of its GUI, and the actions that join them.

Every key and review button goes through `press`, which runs as the key's message arrives (an
async viser callback) and records what the client was last sent (`SceneView.shown`); the action
itself then runs on the tab's one action thread, in the order the keys came. A key whose track is
no longer the one it was pressed on (a second `A`), or whose track another tab changed since it
was drawn, is dropped with a notice and sends nothing. Changes made elsewhere arrive through the
viewer's change feed (`service_changed`): the tab re-reads its track and redraws.
"""

from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor
from typing import TYPE_CHECKING, Any

import numpy as np
import viser

from annotator_ui.actions import AFTER_CLASSES, BEFORE_CLASSES, Action, class_actions
from annotator_ui.bulk_panel import BulkPanel
from annotator_ui.client import ApiClient, ApiError, NothingToUndo, StaleEdit
from annotator_ui.colours import legend_html
from annotator_ui.geometry import pick_point, pose_matrix
from annotator_ui.ground_panel import GroundPanel
from annotator_ui.ground_regions import GroundView, ground_map
from annotator_ui.panels import AnchorsPanel, JobsPanel, ProgressPanel, StitchesPanel
from annotator_ui.playback import Playback
from annotator_ui.prefetch import prefetch_next
from annotator_ui.repair_panel import RepairPanel
from annotator_ui.review import NoChange, ReviewSession
from annotator_ui.review_panel import (
    ReviewPanel,
    empty_queue_message,
    predicted_info,
    sequence_label,
    track_info,
)
from annotator_ui.route_map import route_image
from annotator_ui.samples import blank_image, sample_image
from annotator_ui.scene_view import SceneView, Shown
from annotator_ui.track_views_panel import hard_to_read

if TYPE_CHECKING:
    from annotator_ui.viewer import AnnotatorViewer

_NOW = object()  # run_action's default: bind to what is on screen at the call
GEOMETRY = ("split", "merge", "undo")  # actions that may rewrite frames
PROGRESS_DELAY_S = 2.0  # progress is refreshed at most this often: fast keys do not wait on its queries


class ClientTab:
    """One browser tab: its GUI, scene, review session and playback."""

    def __init__(self, viewer: AnnotatorViewer, client: viser.ClientHandle, api: ApiClient, user: dict[str, Any]):
        self.viewer, self.client, self.api, self.user = viewer, client, api, user
        self.session = ReviewSession(api, viewer.coordinator)
        self.cache = viewer.cache
        self._busy = threading.RLock()  # one action at a time
        self._keys = ThreadPoolExecutor(max_workers=1, thread_name_prefix=f"keys-{client.client_id}")  # in key order
        self._closed = threading.Event()
        self._own: set[tuple[int, int]] = set()  # (track, version) this tab's own edits produced
        self.sequences: dict[int, dict[str, Any]] = {}
        self._progress_timer: threading.Timer | None = None
        self._progress_lock = threading.Lock()
        self._build_gui()
        self._add_commands((*BEFORE_CLASSES, *AFTER_CLASSES))
        self._class_commands = self._add_commands(class_actions(self.review.table))
        client.scene.on_click()(self._on_click)
        client.scene.add_frame("/sensor", axes_length=1.0, axes_radius=0.04)

    def _build_gui(self) -> None:
        gui = self.client.gui
        gui.configure_theme(control_width="large", dark_mode=True, show_logo=False)
        gui.set_panel_label("tracklabel")
        gui.add_markdown(f"Operator **{self.user.get('name')}** · [{self.api.base_url}]({self.api.base_url}/api/v1/docs)")
        tabs = gui.add_tab_group()
        with tabs.add_tab("Review", viser.Icon.EYE):
            self.review = ReviewPanel(gui, self.press, lambda: Playback(gui, self.session, self.render_frame, self._closed,
                                                                        str(self.client.client_id)),
                                      lambda: self.later(self.render_frame), self.viewer.config.follow_camera)
        self.playback: Playback = self.review.playback
        self.views = self.review.views
        cfg = self.viewer.config
        self.scene = SceneView(self.client, self.api, self.cache, self.session, self.views, self.notify,
                               cfg.cloud_budget, cfg.cloud_voxel_m, cfg.side_panels_delay_s)
        self.scene.follow_camera = self.viewer.config.follow_camera
        r = self.review
        r.gui_sequence.on_update(lambda e: self.later(self._switch_sequence) if e.client is not None else None)
        r.gui_open.on_click(lambda _: self._open_typed())
        r.gui_colour.on_update(self._on_colour)
        r.gui_follow.on_update(lambda _: setattr(self.scene, "follow_camera", bool(r.gui_follow.value)))
        with tabs.add_tab("Repair", viser.Icon.CUT):
            self.repair = RepairPanel(gui, self.client.scene, self.split, self.merge, self.frame_pose, self.track_centre,
                                      self.newest_model, self.notify, self.track_points)
        with tabs.add_tab("Ground", viser.Icon.LASSO_POLYGON):
            self.ground = GroundPanel(gui, self.client.scene, self.api, self.notify, self.ground_view, self._recolour,
                                      self._ground_map, self._look_down, self.later)
        self.scene.paint_ground = self.ground.paint
        with tabs.add_tab("Progress", viser.Icon.CHART_BAR):
            self.progress = ProgressPanel(gui, self.api, self.sequence_id)
        with tabs.add_tab("Model", viser.Icon.SPARKLES):
            self.bulk = BulkPanel(gui, self.api, self.notify, self.sequence_id,
                                  lambda tid: self.later(lambda: self.open_track(tid)))
        with tabs.add_tab("Jobs", viser.Icon.CPU):
            self.jobs = JobsPanel(gui, self.api, self.notify, self.sequence_id, is_admin=self.user.get("role") == "admin")
        with tabs.add_tab("Anchors", viser.Icon.ANCHOR):
            self.anchors = AnchorsPanel(gui, self.api, self.notify, self.sequence_id,
                                        lambda tid: self.later(lambda: self.open_track(tid)))
        with tabs.add_tab("Stitches", viser.Icon.LINK):
            self.stitches = StitchesPanel(gui, self.api, self.notify, self.sequence_id,
                                          lambda: self.session.track_id,
                                          lambda tid: self.later(lambda: self.open_track(tid)),
                                          lambda a, b: self.later(lambda: self.merge_pair(a, b)))

    def _add_commands(self, rows: tuple[Action, ...]) -> list[Any]:
        """A command palette entry (with its hotkey) per row."""
        commands = []
        for a in rows:
            cmd = self.client.gui.add_command(a.label, description=a.help, hotkey=a.key)  # type: ignore[arg-type]

            async def triggered(_e: Any, a: Action = a) -> None:  # async: runs as the key arrives
                self.press(a)

            cmd.on_trigger(triggered)
            commands.append(cmd)
        return commands

    def show_label_set(self, sequence_id: int) -> None:
        """Show the classes of the sequence's label set: class buttons and keys, the colours, the
        legend and the class dropdowns of the side panels (nothing changes for the same set)."""
        try:
            table = self.viewer.label_sets.of(self.api, sequence_id)
        except ApiError as exc:
            self.notify("Classes not read", f"the label set of sequence {sequence_id}: {exc.detail}", "yellow")
            return
        if table == self.review.table:
            return
        with self.client.atomic():
            for cmd in self._class_commands:
                cmd.remove()
            self.review.show_classes(table)
            self._class_commands = self._add_commands(class_actions(table))
            self.scene.table = table
            self.review.gui_legend.content = legend_html(self.scene.colour_mode, table)
            for panel in (self.bulk, self.repair, self.anchors, self.progress):
                panel.set_classes(table)

    # ------------------------------------------------------------------ what the tab shows
    def sequence_id(self) -> int | None:
        """The sequence under review: the one picked, else the shown track's."""
        if self.session.sequence_id is not None:
            return self.session.sequence_id
        return None if self.session.track is None else int(self.session.track["sequence_id"])

    def watched_sequence(self) -> int | None:
        """The sequence whose changes this tab follows (the shown track's)."""
        t = self.session.track
        return int(t["sequence_id"]) if t is not None else self.session.sequence_id

    def ground_view(self) -> GroundView | None:
        """The frame shown, as the ground lasso reads it (None before the first draw)."""
        s = self.scene
        if s.frame_points is None or s.frame_ground is None or s.frame_sequence is None:
            return None
        return GroundView(s.frame_points, s.frame_ground, s.frame_pose, s.frame_sequence, s.frame_index)

    def _ground_map(self, sequence_id: int) -> np.ndarray:
        """Every frame's ground of a sequence, world (ground_regions.ground_map), read through the
        frame cache: the Ground tab's top view."""
        frames = self.scene.cache.frames(self.api, sequence_id)

        def each() -> Any:
            for _index, f in sorted(frames.items()):
                p = self.scene.cache.payload(self.api, int(f["id"]))
                yield p.points, p.ground, pose_matrix(f.get("pose"))

        return ground_map(each())

    def _look_down(self, points: np.ndarray) -> None:
        """The camera straight above `points` (the frame shown's coordinates), all of them in view
        (a 60-degree view; a hair off vertical, where the orbit keeps its up)."""
        lo, hi = points.min(axis=0).astype(np.float64), points.max(axis=0).astype(np.float64)
        c = (lo + hi) / 2
        height = max(float(hi[0] - lo[0]), float(hi[1] - lo[1]), 10.0) / (2 * np.tan(np.radians(30.0)))
        self.client.camera.position = (c[0] - 0.01 * height, c[1], hi[2] + height)  # position first (see SceneView)
        self.client.camera.look_at = tuple(c)

    @property
    def frame_points(self) -> np.ndarray | None:
        return self.scene.frame_points

    @property
    def frame_tracks(self) -> np.ndarray | None:
        return self.scene.frame_tracks

    @property
    def timings_ms(self) -> dict[str, float]:
        return self.scene.timings_ms

    def notify(self, title: str, body: str, colour: str = "blue") -> None:
        self.client.add_notification(title, body, auto_close_seconds=5.0, color=colour)  # type: ignore[arg-type]

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        """Pick the sequence, lease the first track and fill the panels (off the connect callback)."""
        try:
            seqs = self.api.sequences()
        except ApiError:
            seqs = []
        self.sequences = {int(s["id"]): s for s in seqs}
        ready = [s for s in seqs if s["status"] == "ready"]
        self.session.sequence_id = int(ready[0]["id"]) if ready else None
        self.review.set_sequences(ready, self.session.sequence_id)
        self._load(lambda: self.session.next())
        for fn in (self.progress.refresh, self.jobs.refresh_types, self.anchors.refresh, self.bulk.refresh,
                   self.ground.refresh):
            self.later(fn)

    def later(self, fn: Any) -> None:
        """Run `fn` in the viewer's pool unless this tab has closed by then."""
        if not self._closed.is_set():  # a side panel's timer may fire after the viewer stopped
            self.viewer.background(lambda: None if self._closed.is_set() else fn())

    def close(self) -> None:
        self._closed.set()
        with self._progress_lock:
            if self._progress_timer is not None:
                self._progress_timer.cancel()
        self.playback.playing.clear()
        self._keys.shutdown(wait=False, cancel_futures=True)
        self.scene.close()
        self.jobs.close()
        self.session.close()

    def _switch_sequence(self) -> None:
        """Review another sequence: give back the queue track and lease the next one of it."""
        chosen = self.review.chosen_sequence()
        with self._busy:
            if chosen is None or chosen == self.session.sequence_id:
                return
            try:
                self.session.drop_ahead()
                if self.session.track is not None and self.session.from_queue:
                    self.api.release(self.session.track["id"])
            except ApiError:
                pass
            self.session.sequence_id = chosen
            self._load(lambda: self.session.next())
        self.later(self.progress.refresh)
        self.later(self.bulk.refresh)
        self.later(self.ground.refresh)

    # ------------------------------------------------------------------ actions
    def press(self, action: Action) -> None:
        """A key or button arrived: bind it to what is on screen now, run it in key order."""
        if self._closed.is_set():
            return
        shown = self.scene.shown
        if action.review is not None:
            self._keys.submit(self._run_logged, action.review, action.arg, shown)
        elif action.call is not None:
            call = action.call
            self._keys.submit(lambda: call(self))

    def _run_logged(self, action: str, arg: str | None, shown: Shown | None) -> None:
        try:
            self.run_action(action, arg, shown)
        except Exception:  # noqa: BLE001 - the key thread must survive a failed action
            import traceback

            traceback.print_exc()

    def run_action(self, action: str, arg: str | None = None, shown: Any = _NOW) -> bool:
        """Run one review action on `shown` (default: what the client was last sent). Dropped with a notice,
        nothing sent, when the session has moved on from that track, or when another tab changed
        it since it was drawn. False if dropped."""
        if shown is _NOW:  # called, not pressed: what was sent is what it means
            shown = self.scene.sent
        with self._busy:
            t = self.session.track
            if action != "undo" and not self._still_shown(shown, action):
                return False
            self.playback.playing.clear()
            if t is None and action not in ("undo", "skip"):
                self.notify("Nothing to review", "The review queue is empty.", "yellow")
                return True
            before = self.session.track_id
            if action == "label":
                assert arg in self.review.table.classes, arg
                self._guarded(lambda: self.session.label(arg), before, action)
            else:  # a session method (truncate, undo, skip, ...), else a service action that settles the track
                run = getattr(self.session, action, None) or (lambda: self.session.finish(action))
                self._guarded(run, before, action)
            return True

    def _still_shown(self, shown: Shown | None, action: str) -> bool:
        t = self.session.track
        seen = None if shown is None else shown.track_id
        if seen != self.session.track_id:
            what = f"track {seen}, which is done" if seen is not None else "no track"
            self.notify("Key ignored", f"'{action}' was meant for {what}; nothing was changed.", "yellow")
            return False
        if shown is not None and t is not None and shown.version != int(t["version"]) \
                and (shown.track_id, int(t["version"])) not in self._own:
            self.notify("Key ignored", f"track {seen} changed (v{shown.version} -> v{t['version']}) before the key "
                        "was handled; look again. Nothing was changed.", "yellow")
            self.render_track(reset_camera=False)
            return False
        return True

    def _guarded(self, fn: Any, before: int | None, action: str = "") -> None:
        """Run one action (busy lock held), say what went wrong, redraw and refresh the panels
        that follow the shown track."""
        t0 = time.perf_counter()
        try:
            fn()
        except NoChange as exc:
            self.notify("Nothing to undo" if "undo" in str(exc) else "Nothing changed", str(exc), "yellow")
            return
        except NothingToUndo as exc:
            self.notify("Nothing to undo", exc.detail, "yellow")
            return
        except StaleEdit as exc:
            self.notify("Not saved: the track changed", f"{exc.detail}. The track was reloaded.", "red")
            self.render_track(reset_camera=False)
            return
        except ApiError as exc:
            self.notify("Action failed", exc.detail, "red")
            return
        t = self.session.track
        if t is not None:
            self._own.add((int(t["id"]), int(t["version"])))
        if action in GEOMETRY and (seq := self.watched_sequence()) is not None:
            self.viewer.feed.poll_now(seq, exclude=self)  # drop the rewritten frames before drawing
        self.scene.timings_ms["action_and_next"] = 1e3 * (time.perf_counter() - t0)
        self.render_track(reset_camera=self.session.track_id != before)
        self._refresh_progress_soon()
        self.scene.after_shown(lambda: self.later(self.stitches.refresh))

    def _refresh_progress_soon(self) -> None:
        """Refresh the progress panel PROGRESS_DELAY_S from now, once for every action until then."""
        with self._progress_lock:
            if self._progress_timer is not None:
                return
            self._progress_timer = threading.Timer(PROGRESS_DELAY_S, self._refresh_progress_now)
            self._progress_timer.daemon = True
            self._progress_timer.start()

    def _refresh_progress_now(self) -> None:
        with self._progress_lock:
            self._progress_timer = None
        if not self._closed.is_set():
            self.later(self.progress.refresh)

    def service_changed(self, tracks: dict[int, dict[str, Any]], frames: dict[int, str]) -> None:
        """The change feed: a track or frame changed in the service (another tab, another operator)."""
        if not self._closed.is_set():
            self._keys.submit(self._follow_service, tracks, frames)

    def shown_regions(self) -> tuple[int, ...]:
        """The ids of the ground regions the tab shows, ascending (the change feed compares them)."""
        return tuple(sorted(r.id for r in self.ground.regions))

    def regions_changed(self) -> None:
        """The change feed: the ground regions of the watched sequence changed (any tab, any operator)."""
        self.later(self.ground.refresh)

    def _recolour(self) -> None:
        """Redraw the frame shown in key order (the ground regions changed its colours)."""
        if not self._closed.is_set():
            self._keys.submit(self._redraw_frame)

    def _redraw_frame(self) -> None:
        with self._busy:
            self.render_frame()

    def _follow_service(self, tracks: dict[int, dict[str, Any]], frames: dict[int, str]) -> None:
        with self._busy:
            t, shown = self.session.track, self.scene.sent
            if t is None:
                return
            info = tracks.get(int(t["id"]))
            changed = info is not None and int(info["version"]) != int(t["version"])
            redraw = shown is not None and shown.frame_id in frames and frames[shown.frame_id] != shown.etag
            if not changed and not redraw:
                return
            if changed:
                try:
                    self.session.reload()
                except ApiError as exc:
                    self.notify("Track gone", f"track {t['id']} is no longer in the service ({exc.detail})", "yellow")
                    self._load(lambda: self.session.next())
                    return
                self.notify("Track changed elsewhere", f"track {t['id']} is now v{self.session.track['version']}; "  # type: ignore[index]
                            "redrawn as the service holds it.", "blue")
            self.render_track(reset_camera=False)
        self.scene.after_shown(lambda: self.later(self.stitches.refresh))

    def split(self, region: dict[str, Any], this_frame_only: bool) -> None:
        """Cut the shown track by a region (repair panel); the shown track stays on screen."""
        with self._busy:
            if self.session.track is None:
                return
            before = self.session.track_id
            done: dict[str, Any] = {}
            self._guarded(lambda: done.update(self.session.split(region, this_frame_only)), before, "split")
            if done:
                self.notify("Track split", f"{done['moved_points']} points went to new track {done['new_track']['id']}.", "green")

    def merge(self, other_id: int) -> None:
        """Join track `other_id` into the shown track."""
        with self._busy:
            if self.session.track is None:
                return
            self._guarded(lambda: self.session.merge(other_id), self.session.track_id, "merge")

    def merge_pair(self, a: int, b: int) -> None:
        """Merge the two tracks of a stitch: show `a`, join `b` into it."""
        if self.session.track_id != a:
            self.open_track(a)
        if self.session.track_id == a:
            self.merge(b)

    def newest_model(self) -> int | None:
        """The id of the newest registered model (split by predicted class), None without one."""
        try:
            models = self.api.get("/models", limit=1)
        except ApiError:
            return None
        return int(models[0]["id"]) if models else None

    def frame_pose(self) -> np.ndarray:
        """T_world_lidar of the frame shown (the scene's frame)."""
        t, fi = self.session.track, self.session.frame_index
        if t is None or fi is None:
            return np.eye(4)
        frame = self.cache.frames(self.api, int(t["sequence_id"])).get(fi)
        return pose_matrix(None if frame is None else frame.get("pose"))

    def track_centre(self) -> np.ndarray | None:
        """The shown track's centre in the scene (its points in this frame, else None)."""
        pts, tracks, tid = self.frame_points, self.frame_tracks, self.session.track_id
        if pts is not None and tracks is not None and tid is not None and (tracks == tid).any():
            return pts[tracks == tid].mean(axis=0)
        return None

    def track_points(self) -> np.ndarray:
        """(K, 3) the shown track's points in the shown frame (scene frame)."""
        pts, tracks, tid = self.frame_points, self.frame_tracks, self.session.track_id
        if pts is None or tracks is None or tid is None:
            return np.zeros((0, 3), np.float32)
        return pts[tracks == tid]

    def open_track(self, track_id: int) -> None:
        with self._busy:
            self.playback.playing.clear()
            before = self.session.track_id
            self._load(lambda: self.session.open(track_id))
            if self.session.track_id == track_id != before:
                if self.session.held_by:
                    self.notify("Track held by another operator", self.session.held_by, "yellow")
                else:
                    self.notify("Track picked", f"Reviewing track {track_id} out of queue order.", "blue")

    def _open_typed(self) -> None:
        text = self.review.gui_goto.value.strip().lstrip("#")
        if not text.isdigit() or int(text) < 1:
            self.notify("Not a track id", f"{text!r} is not a track id", "yellow")
            return
        self.open_track(int(text))

    def _load(self, fn: Any) -> None:
        try:
            fn()
        except ApiError as exc:
            self.notify("Cannot load a track", exc.detail, "red")
        self.render_track(reset_camera=True)
        self.scene.after_shown(lambda: self.later(self.stitches.refresh))  # the shown track's stitches

    # ------------------------------------------------------------------ picking and colours
    def _on_click(self, event: viser.SceneClickEvent) -> None:
        if self.ground.drawing:  # the lasso takes the clicks while it draws
            self.ground.clicked(np.asarray(event.ray_origin), np.asarray(event.ray_direction))
            return
        pts, tracks = self.frame_points, self.frame_tracks
        if pts is None or tracks is None:
            return
        i = pick_point(pts, np.asarray(event.ray_origin), np.asarray(event.ray_direction), candidates=tracks > 0)
        if i < 0:
            return
        track_id = int(tracks[i])
        if track_id == self.session.track_id:
            return
        if self.repair.wants_click():
            self.repair.clicked(track_id)
        else:
            self.later(lambda: self.open_track(track_id))

    def _on_colour(self, event: viser.GuiEvent) -> None:
        self.scene.colour_mode = self.review.gui_colour.value  # type: ignore[assignment]
        self.review.gui_legend.content = legend_html(self.scene.colour_mode, self.review.table)
        if event.client is not None and self.session.track is not None:
            self.render_frame()

    # ------------------------------------------------------------------ drawing
    def render_track(self, reset_camera: bool) -> None:
        """Show the session's track: its info, the frame slider, then its current frame."""
        t = self.session.track
        self.playback.enable(t is not None)
        if t is None:
            self.review.gui_track.content = empty_queue_message(self.api, self.session.sequence_id)
            self.scene.clear()
            self.review.gui_sample.image = blank_image()
            return
        self.show_label_set(int(t["sequence_id"]))
        self.views.track_hard = hard_to_read(t)
        with self.client.atomic():
            self.playback.fit()
        self.render_frame(reset_camera=reset_camera)
        if self.viewer.config.prefetch:  # after the draw is on its way: the next track while the operator decides
            self.later(lambda: prefetch_next(self.session, self.api, self.cache, self.scene.prepare_cloud))

    def render_frame(self, reset_camera: bool = False) -> bool:
        """Draw the current frame of the session's track. False when it could not be read."""
        t, fi = self.session.track, self.session.frame_index
        if t is None or fi is None:
            return False

        def texts() -> None:
            seq = self.sequences.get(int(t["sequence_id"]))
            name = sequence_label(seq) if seq else f"#{t['sequence_id']}"
            self.review.gui_track.content = track_info(t, fi, self.session.from_queue, name,
                                                       self.scene.drawn_points(int(t["id"])))
            predicted = predicted_info(t, self.review.actions)
            if self.review.gui_predicted.content != predicted:  # an unchanged text costs the browser nothing
                self.review.gui_predicted.content = predicted

        if not self.scene.render(texts, reset_camera=reset_camera):
            return False
        self.ground.draw()  # the lasso's outlines follow the frame
        if self.ground.sequence_id != self.scene.frame_sequence:  # a track of another sequence
            self.later(self.ground.refresh)
        gen, seg = self.scene.generation, self.session.segment_at(fi)
        self.scene.after_shown(lambda: self.later(lambda: self._load_sample(gen, seg)))
        if reset_camera:
            self.repair.place(self.track_centre())
            self.scene.after_shown(lambda: self.later(lambda: self._draw_route(t)))
        elif self.repair.gizmo is not None:
            self.repair.preview()  # the count follows the frame
        return True

    def _draw_route(self, t: dict[str, Any]) -> None:
        """The route overview of a newly shown track (off the key's path: one image per track)."""
        if self.session.track_id == int(t["id"]):
            frames = self.cache.frames(self.api, int(t["sequence_id"]))
            self.review.gui_route.image = route_image(t, frames)

    def _load_sample(self, gen: int, seg: dict[str, Any] | None) -> None:
        image = blank_image()
        if seg is not None and seg.get("sample_url"):
            try:
                image = sample_image(self.api.sample_png(seg["sample_url"]))
            except ApiError:
                pass
        if gen == self.scene.generation:  # a newer frame was drawn meanwhile: its own load shows its sample
            self.review.gui_sample.image = image
