"""The annotator: a viser server where each browser tab reviews tracks of the track service.

`AnnotatorViewer` builds the server; every connecting client gets its own `ClientTab` (its GUI
handles, scene nodes, `ReviewSession` and playback thread), set up in `on_client_connect` and
kept per client id on the viewer instance (no module globals). The viewer reaches the service only
through `annotator_ui.client.ApiClient`.

Scene: the current frame's lidar frame (sensor at the origin, z up), points in float32.
  /frame/points   every point of the frame, coloured by the colour mode, faded around the track
  /frame/track    the reviewed track's points in this frame in their real colours (height or
                  intensity; grey outside the kept range)
  /frame/outline  a box around them (the halo that finds the track without hiding its shape)
  /track/aggregate  the points of all kept frames overlaid (only while "Aggregate" is ticked)
  /track/path     the track's centroids over its frames (world centroids moved into this frame)
  /track/nodes    those centroids, small; orange inside the kept range, grey outside, white = this frame
  /cut            the split box / plane gizmo (repair panel)
"""

from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np
import viser

from annotator_ui.bulk_panel import BulkPanel
from annotator_ui.client import ApiClient, ApiError, NothingToUndo, StaleEdit
from annotator_ui.colours import COLOUR_MODES, ColourMode, fade, legend_html, point_colours
from annotator_ui.frame_cache import FrameCache
from annotator_ui.geometry import pick_point, polyline_segments, pose_matrix, world_to_lidar
from annotator_ui.panels import AnchorsPanel, JobsPanel, ProgressPanel, StitchesPanel
from annotator_ui.repair_panel import RepairPanel
from annotator_ui.review import NoChange, QueueCoordinator, ReviewSession
from annotator_ui.samples import blank_image, sample_image
from annotator_ui.track_look import OUTLINE, aggregate, box_outline, track_colours
from annotator_ui.track_views_panel import TrackViewsPanel, frame_cuts
from pipeline.classes import SAMPLE_CLASSES

HOTKEYS: tuple[tuple[str, str, str], ...] = (
    # (command label, hotkey, description)
    ("Accept track", "A", "accept the track as it is and load the next one"),
    ("Discard track", "D", "discard the track (a wrong association) and load the next one"),
    ("Truncate before frame", "[", "keep the current frame and the ones after it"),
    ("Truncate after frame", "]", "keep the current frame and the ones before it"),
    ("Undo", "Z", "revert this tab's last action and show that track"),
    ("Skip track", "S", "pass this track over and load the next one"),
    ("Previous frame", "arrowleft", "step one frame back"),
    ("Next frame", "arrowright", "step one frame forward"),
    ("Play / pause", "space", "play the track's frames"),
    ("Split by height", "H", "cut the track's points above the set height into a new track"),
    ("Split by predicted class", "P", "cut the segments the newest model calls the chosen class into a new track"),
    *((f"Class {name}", str(i + 1), f"label the track '{name}' (accepts it) and load the next one")
      for i, name in enumerate(SAMPLE_CLASSES)),
)
PLAY_FPS = 5.0
POINT_SIZE = 0.06
TRACK_POINT_SIZE = 0.08  # a little larger than the rest: dense enough to read the shape, never a blob
NODE_SIZE = 0.12  # path markers small enough not to cover a pedestrian
OUTSIDE_KEPT = (150, 150, 150)
PATH_KEPT = (255, 140, 0)
KEY_HELP = ("**A** accept · **D** discard · **1-7** class · **[** / **]** truncate before / after · **Z** undo · "
            "**S** skip · **←/→** frame · **space** play · **H** / **P** split by height / predicted class · "
            "click a point: open its track")
# masks what is typed into the sign-in page's only text field (Chromium and WebKit)
MASK_TOKEN_CSS = "<style>.mantine-TextInput-input{-webkit-text-security:disc}</style>"


def class_button_labels() -> list[str]:
    """'1 person', '2 car', ...: each class button shows its number key."""
    return [f"{i + 1} {name}" for i, name in enumerate(SAMPLE_CLASSES)]


def class_of_button(label: str) -> str:
    return label.split(" ", 1)[1]


@dataclass(frozen=True)
class ViewerConfig:
    api_url: str
    token: str | None = None  # None: each tab signs in with its operator's token
    host: str = "127.0.0.1"
    port: int = 8080
    cache_mb: int = 256
    follow_camera: bool = True


class ClientTab:
    """One browser tab: its GUI, scene, review session and playback."""

    def __init__(self, viewer: AnnotatorViewer, client: viser.ClientHandle, api: ApiClient, user: dict[str, Any]):
        self.viewer = viewer
        self.client = client
        self.api = api
        self.user = user
        self.session = ReviewSession(api, viewer.coordinator)
        self.cache = viewer.cache
        self._busy = threading.Lock()  # one action at a time; keys pressed meanwhile wait (see run_action)
        self._render_lock = threading.Lock()
        self._render_gen = 0
        self._playing = threading.Event()
        self._closed = threading.Event()
        self._player: threading.Thread | None = None
        self.colour_mode: ColourMode = "track"
        self.frame_points: np.ndarray | None = None  # (N, 3) float32 points of the frame shown
        self.frame_tracks: np.ndarray | None = None  # (N,) track id per point
        self.timings_ms: dict[str, float] = {}  # stages of the last action and frame drawn
        self._build_gui()
        self._build_commands()
        client.scene.on_click()(self._on_click)
        client.scene.add_frame("/sensor", axes_length=1.0, axes_radius=0.04)

    # ------------------------------------------------------------------ GUI
    def _build_gui(self) -> None:
        gui = self.client.gui
        gui.configure_theme(control_width="large", dark_mode=True, show_logo=False)
        gui.set_panel_label("tracklabel")
        gui.add_markdown(f"Operator **{self.user.get('name')}** · [{self.api.base_url}]({self.api.base_url}/api/v1/docs)")
        tabs = gui.add_tab_group()
        with tabs.add_tab("Review", viser.Icon.EYE):
            self.gui_keys = gui.add_markdown(KEY_HELP)  # first: visible without scrolling
            self.gui_track = gui.add_markdown("Loading the review queue ...")
            self.gui_frame = gui.add_slider("Frame", min=0, max=1, step=1, initial_value=0, disabled=True)
            self.gui_frame.on_update(self._on_slider)
            self.gui_play = gui.add_button("Play", icon=viser.Icon.PLAYER_PLAY, disabled=True)
            self.gui_play.on_click(lambda _: self.toggle_play())
            self.gui_sample = gui.add_image(blank_image(), label="Sample (height · range · intensity · mask)", format="png")
            self.gui_accept = gui.add_button("Accept (A)", color="green", icon=viser.Icon.CHECK)
            self.gui_accept.on_click(lambda _: self.run_action("accept"))
            self.gui_discard = gui.add_button("Discard (D)", color="red", icon=viser.Icon.TRASH)
            self.gui_discard.on_click(lambda _: self.run_action("discard"))
            self.gui_truncate = gui.add_button_group("Truncate", ("[ before frame", "after frame ]"))
            self.gui_truncate.on_click(
                lambda e: self.run_action("truncate_before" if e.target.value.startswith("[") else "truncate_after")
            )
            self.gui_predicted = gui.add_markdown("Model: no prediction for this track")
            labels = class_button_labels()
            self.gui_class_a = gui.add_button_group("Class 1-4", labels[:4])
            self.gui_class_b = gui.add_button_group("Class 5-7", labels[4:])
            for group in (self.gui_class_a, self.gui_class_b):
                group.on_click(lambda e: self.run_action("label", class_of_button(e.target.value)))
            self.gui_undo = gui.add_button("Undo (Z)", icon=viser.Icon.ARROW_BACK_UP)
            self.gui_undo.on_click(lambda _: self.run_action("undo"))
            self.gui_skip = gui.add_button("Skip (S)", icon=viser.Icon.PLAYER_SKIP_FORWARD)
            self.gui_skip.on_click(lambda _: self.run_action("skip"))
            self.gui_goto = gui.add_text("Open track #", initial_value="", hint="review a track by its id")
            self.gui_open = gui.add_button("Open track", icon=viser.Icon.SEARCH)
            self.gui_open.on_click(lambda _: self._open_typed())
            self.gui_colour = gui.add_dropdown("Colour by", COLOUR_MODES, initial_value="track")
            self.gui_colour.on_update(self._on_colour)
            self.gui_follow = gui.add_checkbox("Camera follows track", self.viewer.config.follow_camera)
            self.gui_legend = gui.add_html(legend_html("track"))
            with gui.add_folder("Track views"):
                self.views = TrackViewsPanel(gui, lambda: self.later(self.render_frame))
        with tabs.add_tab("Repair", viser.Icon.CUT):
            self.repair = RepairPanel(gui, self.client.scene, self.split, self.merge, self.frame_pose, self.track_centre,
                                      self.newest_model, self.notify)
        with tabs.add_tab("Progress", viser.Icon.CHART_BAR):
            self.progress = ProgressPanel(gui, self.api)
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

    def sequence_id(self) -> int | None:
        """The sequence under review: the shown track's, else the first ready one."""
        if self.session.track is not None:
            return int(self.session.track["sequence_id"])
        try:
            ready = [s for s in self.api.sequences() if s["status"] == "ready"]
        except ApiError:
            return None
        return int(ready[0]["id"]) if ready else None

    def _build_commands(self) -> None:
        actions = {
            "A": ("accept", None), "D": ("discard", None), "[": ("truncate_before", None),
            "]": ("truncate_after", None), "Z": ("undo", None), "S": ("skip", None),
            **{str(i + 1): ("label", name) for i, name in enumerate(SAMPLE_CLASSES)},
        }
        for label, key, description in HOTKEYS:
            cmd = self.client.gui.add_command(label, description=description, hotkey=key)  # type: ignore[arg-type]
            if key in actions:
                action, arg = actions[key]
                cmd.on_trigger(lambda _e, a=action, x=arg: self.run_action(a, x))
            elif key == "arrowleft":
                cmd.on_trigger(lambda _e: self.step_frame(-1))
            elif key == "arrowright":
                cmd.on_trigger(lambda _e: self.step_frame(+1))
            elif key == "space":
                cmd.on_trigger(lambda _e: self.toggle_play())
            elif key == "H":
                cmd.on_trigger(lambda _e: self.repair.cut_height())
            elif key == "P":
                cmd.on_trigger(lambda _e: self.repair.cut_predicted())

    def notify(self, title: str, body: str, colour: str = "blue") -> None:
        self.client.add_notification(title, body, auto_close_seconds=5.0, color=colour)  # type: ignore[arg-type]

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        """Lease the first track and fill the panels (runs off the connect callback)."""
        self._load(lambda: self.session.next())
        self.later(self.progress.refresh)
        self.later(self.jobs.refresh_types)
        self.later(self.anchors.refresh)
        self.later(self.bulk.refresh)

    def later(self, fn: Any) -> None:
        """Run `fn` in the viewer's pool unless this tab has closed by then."""
        self.viewer.background(lambda: None if self._closed.is_set() else fn())

    def close(self) -> None:
        self._closed.set()
        self._playing.clear()
        self.jobs.close()
        self.session.close()

    # ------------------------------------------------------------------ actions
    def run_action(self, action: str, arg: str | None = None) -> bool:
        """Run one review action on the track shown when the key arrived. Keys pressed during an
        action wait their turn; one whose track was finished meanwhile (say a second A) is dropped
        with a notice, so no key ever acts on a track the operator has not seen. False if dropped."""
        seen = self.session.track_id
        if not self._busy.acquire(timeout=60.0):
            return False
        try:
            if action != "undo" and self.session.track_id != seen:
                self.notify("Key ignored", f"'{action}' was meant for track {seen}, which is done.", "yellow")
                return False
            self._playing.clear()
            if self.session.track is None and action not in ("undo", "skip"):
                self.notify("Nothing to review", "The review queue is empty.", "yellow")
                return True
            before = self.session.track_id
            fn = {
                "accept": self.session.accept,
                "discard": self.session.discard,
                "truncate_before": self.session.truncate_before,
                "truncate_after": self.session.truncate_after,
                "undo": self.session.undo,
                "skip": self.session.skip,
            }
            if action == "label":
                assert arg in SAMPLE_CLASSES, arg
                self._guarded(lambda: self.session.label(arg), before)
            else:
                self._guarded(fn[action], before)
            return True
        finally:
            self._busy.release()

    def _guarded(self, fn: Any, before: int | None) -> None:
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
        self.timings_ms["action_and_next"] = 1e3 * (time.perf_counter() - t0)
        self.render_track(reset_camera=self.session.track_id != before)
        self.later(self.progress.refresh)
        self.later(self.stitches.refresh)

    def split(self, region: dict[str, Any], this_frame_only: bool) -> None:
        """Cut the shown track by a region (repair panel); the shown track stays on screen."""
        with self._busy:
            if self.session.track is None:
                return
            before = self.session.track_id
            done: dict[str, Any] = {}
            self._guarded(lambda: done.update(self.session.split(region, this_frame_only)), before)
            if done:
                self.notify("Track split", f"{done['moved_points']} points went to new track {done['new_track']['id']}.", "green")

    def merge(self, other_id: int) -> None:
        """Join track `other_id` into the shown track."""
        with self._busy:
            if self.session.track is None:
                return
            before = self.session.track_id
            self._guarded(lambda: self.session.merge(other_id), before)

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
        """The shown track's centre in the scene (its points in this frame, else its centroid)."""
        pts, tracks, tid = self.frame_points, self.frame_tracks, self.session.track_id
        if pts is not None and tracks is not None and tid is not None and (tracks == tid).any():
            return pts[tracks == tid].mean(axis=0)
        return None

    def open_track(self, track_id: int) -> None:
        with self._busy:
            self._playing.clear()
            before = self.session.track_id
            self._load(lambda: self.session.open(track_id))
            if self.session.track_id == track_id != before:
                if self.session.held_by:
                    self.notify("Track held by another operator", self.session.held_by, "yellow")
                else:
                    self.notify("Track picked", f"Reviewing track {track_id} out of queue order.", "blue")

    def _open_typed(self) -> None:
        text = self.gui_goto.value.strip().lstrip("#")
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
        self.later(self.stitches.refresh)  # the shown track's stitches

    # ------------------------------------------------------------------ frames and playback
    def _on_slider(self, event: viser.GuiEvent) -> None:
        if event.client is None or self.session.track is None:  # set by the server, already drawn
            return
        self._show_frame(int(self.gui_frame.value))

    def _show_frame(self, index: int) -> None:
        """Draw frame `index`; when it cannot be drawn (service down) the slider and the session
        go back to the frame still on the canvas, so the two never disagree."""
        shown = self.session.frame_index
        self.session.set_frame(index)
        if not self.render_frame() and shown is not None:
            self.session.set_frame(shown)
        self.gui_frame.value = self.session.frame_index

    def _on_colour(self, event: viser.GuiEvent) -> None:
        self.colour_mode = self.gui_colour.value  # type: ignore[assignment]
        self.gui_legend.content = legend_html(self.colour_mode)
        if event.client is not None and self.session.track is not None:
            self.render_frame()

    def step_frame(self, delta: int) -> None:
        if self.session.track is None:
            return
        lo, hi = self.session.frame_range()
        idx = self.session.frame_index or lo
        self._show_frame(lo + (idx - lo + delta) % (hi - lo + 1))

    def toggle_play(self) -> None:
        if self._playing.is_set():
            self._playing.clear()
            return
        if self.session.track is None:
            return
        self._playing.set()
        self.gui_play.label, self.gui_play.icon = "Pause", viser.Icon.PLAYER_PAUSE
        if self._player is None or not self._player.is_alive():
            self._player = threading.Thread(target=self._play, name=f"play-{self.client.client_id}", daemon=True)
            self._player.start()

    def _play(self) -> None:
        try:
            while self._playing.is_set() and not self._closed.is_set():
                t0 = time.perf_counter()
                self.step_frame(+1)
                self._closed.wait(max(0.0, 1.0 / PLAY_FPS - (time.perf_counter() - t0)))
        finally:
            self._playing.clear()
            self.gui_play.label, self.gui_play.icon = "Play", viser.Icon.PLAYER_PLAY

    # ------------------------------------------------------------------ picking
    def _on_click(self, event: viser.SceneClickEvent) -> None:
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

    # ------------------------------------------------------------------ drawing
    def render_track(self, reset_camera: bool) -> None:
        """Show the session's track: its info, the frame slider, then its current frame."""
        t = self.session.track
        has = t is not None
        for h in (self.gui_frame, self.gui_play):
            h.disabled = not has
        if t is None:
            self.gui_track.content = self._empty_queue_message()
            for name in ("/frame/track", "/frame/outline", "/track/aggregate", "/track/path", "/track/nodes"):
                self.client.scene.remove_by_name(name)
            self.gui_sample.image = blank_image()
            return
        lo, hi = self.session.frame_range()
        with self.client.atomic():
            # widen first, so the value always lies inside the bounds
            self.gui_frame.min, self.gui_frame.max = min(lo, self.gui_frame.min), max(hi, self.gui_frame.max)
            self.gui_frame.value = self.session.frame_index
            self.gui_frame.min, self.gui_frame.max = lo, max(hi, lo + 1)  # a 1-frame track keeps a usable slider
            self.gui_frame.disabled = hi == lo
        self.render_frame(reset_camera=reset_camera)

    def _empty_queue_message(self) -> str:
        """Why no track is shown: a failed or empty ingest says so, else everything is reviewed."""
        try:
            seqs = self.api.sequences()
            stats = self.api.stats()
        except ApiError as exc:
            return f"**No track shown:** the track service cannot be read ({exc.detail})."
        failed = [s for s in seqs if s["status"] == "failed"]
        busy = [s for s in seqs if s["status"] in ("registered", "ingesting")]
        lines = [f"**Ingest of sequence {s['name']} (#{s['id']}) failed** (job #{s['ingest_job_id']}); "
                 f"it has no tracks to review. An admin can see the job's error and ingest it again." for s in failed]
        lines += [f"Sequence {s['name']} (#{s['id']}) is {s['status']}; its tracks appear when the ingest is done."
                  for s in busy]
        if int(stats.get("tracks", 0)) == 0:
            lines.append("**No tracks:** no ingested sequence holds a track (nothing was segmented).")
        elif not failed and not busy:
            lines.append("**All tracks are reviewed** (or leased to other operators). Press **Z** to undo, or "
                         "click a point to revisit its track.")
        return "  \n".join(lines)

    def _track_info(self, frame_index: int) -> str:
        t = self.session.track
        assert t is not None
        pred = ""
        if t.get("predicted_class"):
            conf = t.get("predicted_confidence")
            pred = f" · predicted **{t['predicted_class']}**" + (f" ({100 * conf:.0f} %)" if conf is not None else "")
        where = "queue" if self.session.from_queue else "picked"
        kept = t["keep_start"] <= frame_index <= t["keep_end"]
        return (
            f"**Track {t['id']}** ({where}) · {t['status']}" + (f" · **{t['label']}**" if t.get("label") else "")
            + pred + "  \n"
            f"frames {t['first_frame']}-{t['last_frame']} · kept {t['keep_start']}-{t['keep_end']} · "
            f"{t['n_samples']} samples · v{t['version']}  \n"
            f"frame **{frame_index}**" + ("" if kept else " (outside the kept range)")
        )

    def render_frame(self, reset_camera: bool = False) -> bool:
        """Draw the current frame of the session's track and send it to this client. False when
        the frame could not be read (nothing on the canvas changed)."""
        with self._render_lock:
            t0 = time.perf_counter()
            self._render_gen += 1
            gen = self._render_gen
            t = self.session.track
            fi = self.session.frame_index
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
            colours = fade(point_colours(payload.segment, payload.track, self.colour_mode, info), mask)
            t_coloured = time.perf_counter()
            # what the canvas shows is known before the client sees it (a click or a cut may
            # arrive as soon as the cloud does)
            self.frame_points, self.frame_tracks = payload.points, payload.track
            with self.client.atomic():
                self.client.scene.add_point_cloud("/frame/points", payload.points, colours, point_size=POINT_SIZE,
                                                  precision="float32", point_shading="flat")
                self._draw_track(t, fi, payload, mask, aggregated)
                self._draw_path(t, fi, pose_matrix(frame.get("pose")))
                self.gui_track.content = self._track_info(fi)
                predicted = self._predicted_info(t)
                if self.gui_predicted.content != predicted:  # an unchanged text costs the browser nothing
                    self.gui_predicted.content = predicted
                if reset_camera and self.gui_follow.value:
                    self._aim_camera(t, fi, payload.points[mask])
            self.client.flush()
            t_sent = time.perf_counter()
            self.timings_ms.update(frame_fetch=1e3 * (t_fetched - t0), colour=1e3 * (t_coloured - t_fetched),
                                   send=1e3 * (t_sent - t_coloured))
        seg = self.session.segment_at(fi)
        self.later(lambda: self._load_sample(gen, seg))
        if reset_camera:
            self.repair.place(self.track_centre())
        return True

    def _aggregated(self, t: dict[str, Any], frame: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
        """The kept frames' track points overlaid, in this frame's scene: (M, 3) points, (M,) intensity."""
        frames = self.cache.frames(self.api, int(t["sequence_id"]))
        cuts = frame_cuts(t, frames, lambda fid: self.cache.payload(self.api, fid))
        seg = self.session.segment_at(int(frame["index"]))
        anchor = np.asarray(seg["centroid_world"], np.float64) if seg is not None else None
        pts_world, intensity = aggregate(cuts, self.views.compensated, anchor)
        return world_to_lidar(pts_world, pose_matrix(frame.get("pose"))), intensity

    def _draw_track(self, t: dict[str, Any], fi: int, payload: Any, mask: np.ndarray,
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
        path = world_to_lidar(np.array([s["centroid_world"] for s in segs], np.float64), T_world_lidar)
        node_colours = np.array(
            [(255, 255, 255) if s["frame_index"] == fi else (PATH_KEPT if s["in_kept_range"] else OUTSIDE_KEPT)
             for s in segs], np.uint8)
        scene = self.client.scene
        if len(path) >= 2:
            seg_colours = np.repeat(node_colours[1:, None, :], 2, axis=1)
            scene.add_line_segments("/track/path", polyline_segments(path), seg_colours, thickness=0.03)
        else:
            scene.remove_by_name("/track/path")
        scene.add_point_cloud("/track/nodes", path, node_colours, point_size=NODE_SIZE, precision="float32",
                              point_shape="circle", point_shading="flat")

    @staticmethod
    def _predicted_info(t: dict[str, Any]) -> str:
        """The model's class and confidence, shown beside the class buttons."""
        if not t.get("predicted_class"):
            return "Model: no prediction for this track"
        conf = t.get("predicted_confidence")
        key = SAMPLE_CLASSES.index(t["predicted_class"]) + 1 if t["predicted_class"] in SAMPLE_CLASSES else None
        return (f"Model: **{t['predicted_class']}**" + (f" ({100 * conf:.0f} %)" if conf is not None else "")
                + (f" · key **{key}**" if key else ""))

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

    def _load_sample(self, gen: int, seg: dict[str, Any] | None) -> None:
        image = blank_image()
        if seg is not None and seg.get("sample_url"):
            try:
                image = sample_image(self.api.sample_png(seg["sample_url"]))
            except ApiError:
                pass
        if gen == self._render_gen:  # a newer frame was drawn meanwhile: its own load shows its sample
            self.gui_sample.image = image


class AnnotatorViewer:
    """The viser server of the annotator. Non-blocking: `serve_forever()` blocks, `stop()` ends it."""

    def __init__(self, config: ViewerConfig, verbose: bool = False) -> None:
        self.config = config
        self.cache = FrameCache(config.cache_mb * 2**20)
        self.coordinator = QueueCoordinator()
        self.tabs: dict[int, ClientTab] = {}
        self._tabs_lock = threading.Lock()
        self._pool = ThreadPoolExecutor(max_workers=4, thread_name_prefix="annotator-bg")
        self.server = viser.ViserServer(host=config.host, port=config.port, label="tracklabel", verbose=verbose)
        self.server.scene.set_up_direction("+z")
        self.server.initial_camera.position = (-18.0, -18.0, 16.0)
        self.server.initial_camera.look_at = (0.0, 0.0, 0.0)
        self.server.on_client_connect(self._on_connect)
        self.server.on_client_disconnect(self._on_disconnect)

    @property
    def port(self) -> int:
        return int(self.server.get_port())

    @property
    def url(self) -> str:
        host = "127.0.0.1" if self.config.host in ("0.0.0.0", "::") else self.config.host
        return f"http://{host}:{self.port}"

    def background(self, fn: Any) -> None:
        """Run `fn` off the GUI callback; its errors are printed, never raised into viser."""

        def run() -> None:
            try:
                fn()
            except Exception:  # noqa: BLE001 - a background refresh must not kill the pool
                import traceback

                traceback.print_exc()

        self._pool.submit(run)

    def tab(self, client_id: int) -> ClientTab | None:
        with self._tabs_lock:
            return self.tabs.get(client_id)

    # ------------------------------------------------------------------ clients
    def _on_connect(self, client: viser.ClientHandle) -> None:
        if self.config.token:
            self._sign_in(client, self.config.token, form=None)
            return
        gui = client.gui
        gui.configure_theme(control_width="large", dark_mode=True, show_logo=False)  # the review page's theme
        folder = gui.add_folder("Sign in")
        with folder:
            gui.add_markdown("Paste your tracklabel token (`tracklabel user add NAME` prints one).")
            gui.add_html(MASK_TOKEN_CSS)  # a password field: viser's text input has no masked mode
            token = gui.add_text("Token", initial_value="")
            button = gui.add_button("Sign in", color="green")
        button.on_click(lambda _: self._sign_in(client, token.value.strip(), form=folder))

    def _sign_in(self, client: viser.ClientHandle, token: str, form: Any) -> None:
        api = ApiClient(self.config.api_url, token)
        try:
            user = api.me()
        except ApiError as exc:
            api.close()
            msg = "the token was not accepted" if exc.status == 401 else exc.detail
            client.add_notification("Sign-in failed", msg, auto_close_seconds=8.0, color="red")
            if form is None:
                client.gui.add_markdown(f"**The viewer cannot reach the track service:** {msg}")
            return
        if form is not None:
            form.remove()
        tab = ClientTab(self, client, api, user)
        with self._tabs_lock:
            self.tabs[client.client_id] = tab
        tab.start()

    def _on_disconnect(self, client: viser.ClientHandle) -> None:
        with self._tabs_lock:
            tab = self.tabs.pop(client.client_id, None)
        if tab is not None:
            tab.close()
            tab.api.close()

    # ------------------------------------------------------------------ running
    def serve_forever(self) -> None:
        try:
            while True:
                time.sleep(3600)
        except KeyboardInterrupt:
            pass
        finally:
            self.stop()

    def stop(self) -> None:
        with self._tabs_lock:
            tabs = list(self.tabs.values())
            self.tabs.clear()
        for tab in tabs:
            tab.close()
        self.server.stop()
        self._pool.shutdown(wait=False, cancel_futures=True)
