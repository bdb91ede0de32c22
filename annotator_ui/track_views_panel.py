"""The track views panel: how the reviewed track is coloured (height or intensity), its
aggregated view (the points of all its kept frames overlaid, loaded only when ticked) and its
top and side orthographic images, in a panel docked at the left edge of the 3D view (beside it,
never below the fold of the control panel), shown while they are ticked.

The aggregated cloud is built from the frame payloads of the kept frames (the viewer's frame
cache): each frame's track points go to the world frame with that frame's pose; with motion
compensation each frame is shifted by the track's centroid there, so a moving object lines up.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import viser

from annotator_ui.geometry import pose_matrix
from annotator_ui.samples import blank_image
from annotator_ui.track_look import TRACK_LOOKS, FrameCut, ortho_image

ORTHO_SIZE = 220
# a track this sparse or far is hard to read in one frame: its kept frames are overlaid first
SPARSE_POINTS = 300  # its densest kept frame holds fewer points
FAR_M = 25.0  # its mean range is beyond


def hard_to_read(track: dict[str, Any]) -> bool:
    """Whether the track should open in the aggregated view (sparse or far)."""
    kept = [s for s in track.get("segments", []) if s["in_kept_range"]] or track.get("segments", [])
    densest = max((int(s["n_points"]) for s in kept), default=0)
    return densest < SPARSE_POINTS or float(track.get("mean_range") or 0.0) > FAR_M


def frame_cuts(track: dict[str, Any], frames: dict[int, dict[str, Any]], payload: Callable[[int], Any]) -> list[FrameCut]:
    """The track's points in each kept frame, in the world frame (`payload(frame_id)` gives a
    client.FramePayload; `frames` maps frame index -> FramePublic)."""
    cuts = []
    for seg in sorted(track["segments"], key=lambda s: s["frame_index"]):
        frame = frames.get(seg["frame_index"])
        if not seg["in_kept_range"] or frame is None:
            continue
        p = payload(int(frame["id"]))
        mine = p.track == int(track["id"])
        if not mine.any():
            continue
        T = pose_matrix(frame.get("pose"))
        world = p.points[mine].astype(np.float64) @ T[:3, :3].T + T[:3, 3]
        cuts.append(FrameCut(world, p.intensity[mine], np.asarray(seg["centroid_world"], np.float64)))
    return cuts


class TrackViewsPanel:
    """Colour mode of the track, the aggregated-view switches and the two orthographic images;
    `changed()` (the tab's) redraws when a switch changes."""

    def __init__(self, gui: viser.GuiApi, changed: Callable[[], None]) -> None:
        self.gui_look = gui.add_dropdown("Track colours", TRACK_LOOKS, initial_value="height")
        self.gui_aggregate = gui.add_checkbox("Aggregate kept frames", False, hint="overlay the track's points of all kept frames")
        self.gui_auto = gui.add_checkbox("Aggregate far / sparse tracks first", True,
                                         hint=f"under {SPARSE_POINTS} points a frame or beyond {FAR_M:.0f} m")
        self.track_hard = False  # the shown track is far or sparse (set by the tab)
        self.gui_compensate = gui.add_checkbox("Motion-compensate", False, hint="align the frames by the track's centroids")
        # off by default: two images per frame drawn cost the browser a re-layout on every key
        self.gui_ortho = gui.add_checkbox("Top and side views", False, hint="orthographic images of the track")
        for h in (self.gui_look, self.gui_aggregate, self.gui_auto, self.gui_compensate, self.gui_ortho):
            h.on_update(lambda e: changed() if e.client is not None else None)
        self.gui_views = gui.add_panel(visible=False)  # a top-level window, beside the canvas
        with self.gui_views.add_tab("Track views", viser.Icon.VIEW_360):
            self.gui_top = gui.add_image(blank_image(), label="Top view (1 m grid)", format="png")
            self.gui_side = gui.add_image(blank_image(), label="Side view (1 m grid)", format="png")
        self.gui_views.dock_left()
        self.gui_views.set_width(ORTHO_SIZE + 40)

    @property
    def look(self) -> str:
        return str(self.gui_look.value)

    @property
    def aggregated(self) -> bool:
        return bool(self.gui_aggregate.value) or (bool(self.gui_auto.value) and self.track_hard)

    @property
    def compensated(self) -> bool:
        return bool(self.gui_compensate.value)

    def show(self, points: np.ndarray, colours: np.ndarray) -> None:
        """The orthographic images of (N, 3) scene points with their (N, 3) uint8 colours (when
        the views are ticked)."""
        shown = bool(self.gui_ortho.value)
        if self.gui_views.visible != shown:
            self.gui_views.visible = shown
        if shown:
            self.gui_top.image = ortho_image(points, colours, "top", ORTHO_SIZE)
            self.gui_side.image = ortho_image(points, colours, "side", ORTHO_SIZE)
