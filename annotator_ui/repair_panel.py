"""The repair panel: split the shown track by a box, a plane, a screen rectangle, its height
above ground or the newest model's predicted class (whole segments), and merge another track into it (by a click in the scene; the stitches panel
merges the two tracks of a stitch).

The box and plane are placed with viser's transform controls in the scene (the shown frame's
lidar frame); a cut sends them in the world frame (`T_world_lidar` of the shown frame). The
plane is the gizmo's y-z plane: the points on the side of its red x axis go. A screen rectangle
is drawn with Shift + drag on the canvas and sent with the camera's clip matrix. Every cut and
merge runs through the tab's `run` (one action at a time, errors shown, the track redrawn).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

import numpy as np
import viser

from annotator_ui.cut_preview import PREVIEW_COLOUR, gizmo_scale, inside_box, preview_text
from annotator_ui.geometry import clip_from_scene, matrix_wxyz, rect_polygon_ndc
from annotator_ui.label_set import PAPER, ClassTable
from pipeline.regions import quaternion_matrix

SCOPES = ("All kept frames", "This frame")
BOX_COLOUR = (255, 90, 90)


class RepairPanel:
    """Split tools and merge-by-click; `split(region, this_frame_only)` and `merge(track_id)` are
    the tab's (they run the action and redraw); `pose()` is the shown frame's T_world_lidar,
    `centre()` the shown track's (3,) centre in the scene (None without a track), `model_id()`
    the newest model's id (None without one)."""

    def __init__(
        self,
        gui: viser.GuiApi,
        scene: viser.SceneApi,
        split: Callable[[dict[str, Any], bool], None],
        merge: Callable[[int], None],
        pose: Callable[[], np.ndarray],
        centre: Callable[[], np.ndarray | None],
        model_id: Callable[[], int | None],
        notify: Callable[[str, str, str], None],
        track_points: Callable[[], np.ndarray] = lambda: np.zeros((0, 3), np.float32),
    ) -> None:
        self.scene, self._split, self._merge, self._pose, self._centre = scene, split, merge, pose, centre
        self._model_id, self._notify, self._track_points = model_id, notify, track_points
        self.gizmo: Any = None
        # the gizmo is added, moved, replaced and read from viser's callback threads and the tab's
        # (a typed centre while a new track places it; the checkbox's callback and a cut button
        # both showing it): one at a time, or a thread writes to a handle another just removed
        self._gizmo_lock = threading.RLock()
        # where the gizmo was added, and a centre typed since: the client echoes a new gizmo at
        # the position it was sent a moment after it is added, which must not undo a typed centre
        self._added_at: np.ndarray | None = None
        self._typed: tuple[float, ...] | None = None
        gui.add_markdown("**Split** the track: its points in the region become a new pending track. **Z** undoes.")
        self.gui_show_box = gui.add_checkbox("Show cut box / plane", False)
        self.gui_show_box.on_update(lambda _: self._toggle_gizmo())
        self.gui_size = gui.add_vector3("Box size (m)", (2.0, 2.0, 2.0), min=(0.1, 0.1, 0.1), max=(60.0, 60.0, 60.0), step=0.1)
        self.gui_size.on_update(lambda _: self._draw_box())
        self.gui_centre = gui.add_vector3("Box centre (m)", (0.0, 0.0, 0.0), step=0.05, hint="in the shown frame")
        self.gui_centre.on_update(lambda e: self._typed_centre() if e.client is not None else None)
        self.gui_preview = gui.add_markdown("Cut preview: show the cut box")
        self.gui_cut_box = gui.add_button_group("Cut box", SCOPES)
        self.gui_cut_box.on_click(lambda e: self.cut("box", e.target.value == SCOPES[1]))
        self.gui_cut_plane = gui.add_button_group("Cut plane (red axis side)", SCOPES)
        self.gui_cut_plane.on_click(lambda e: self.cut("plane", e.target.value == SCOPES[1]))
        self.gui_height = gui.add_number("Above ground (m)", 1.0, min=-2.0, max=50.0, step=0.1)
        self.gui_cut_height = gui.add_button("Split by height (H)", icon=viser.Icon.ARROWS_VERTICAL)
        self.gui_cut_height.on_click(lambda _: self.cut_height())
        self.gui_predicted_class = gui.add_dropdown("Predicted as", PAPER.classes, initial_value=PAPER.classes[0])
        self.gui_cut_predicted = gui.add_button("Split off what the model calls it (P)", icon=viser.Icon.BRAIN)
        self.gui_cut_predicted.on_click(lambda _: self.cut_predicted())
        self.gui_screen_scope = gui.add_dropdown("Shift + drag on the canvas cuts", SCOPES, initial_value=SCOPES[0])
        gui.add_markdown("**Merge**: tick, then click a point of the other track (or use a stitch's *Merge*).")
        self.gui_merge_click = gui.add_checkbox("Click merges a track into this one", False)
        scene.on_rect_select(modifier="shift")(self._on_rect)

    def set_classes(self, table: ClassTable) -> None:
        """Offer the classes of `table` (the shown sequence's label set) to split by."""
        table.set_dropdown(self.gui_predicted_class)

    # ------------------------------------------------------------------ gizmo
    def _toggle_gizmo(self) -> None:
        """Show or hide the gizmo as the checkbox says (showing it twice shows one)."""
        with self._gizmo_lock:
            if not self.gui_show_box.value:
                self.scene.remove_by_name("/cut")
                self.scene.remove_by_name("/cut_preview")
                self.gizmo = None
                self.gui_preview.content = "Cut preview: show the cut box"
                return
            if self.gizmo is None:
                centre = self._centre()
                self._add_gizmo(tuple(float(v) for v in centre) if centre is not None else (0.0, 0.0, 0.0))

    def _add_gizmo(self, position: tuple[float, ...]) -> None:
        self._added_at, self._typed = np.asarray(position, np.float64), None
        self.gizmo = self.scene.add_transform_controls(
            "/cut", scale=gizmo_scale(self._track_points()), position=position, depth_test=False
        )
        self.gizmo.on_update(lambda _: self._moved())
        self._draw_box()
        self._moved()

    def _draw_box(self) -> None:
        # under the gizmo's lock: `place` (another thread: a newly shown track) re-adds "/cut",
        # which removes its child box while this one is being made
        with self._gizmo_lock:
            if self.gizmo is not None:
                self.scene.add_box("/cut/box", color=BOX_COLOUR, dimensions=tuple(self.gui_size.value), wireframe=True)
                self.preview()

    def _moved(self) -> None:
        with self._gizmo_lock:
            if self.gizmo is None:
                return
            if self._typed is not None and np.allclose(self.gizmo.position, self._added_at, atol=1e-6):
                self.gizmo.position = self._typed  # the client's echo of the new gizmo: keep what was typed
                return
            self._typed = None  # dragged: the gizmo says where the box is
            self.gui_centre.value = tuple(round(float(v), 3) for v in self.gizmo.position)
            self.preview()

    def _typed_centre(self) -> None:
        with self._gizmo_lock:
            if self.gizmo is not None:
                self._typed = tuple(float(v) for v in self.gui_centre.value)
                self.gizmo.position = self._typed
                self.preview()

    def preview(self) -> int:
        """Count and highlight the track's points of this frame inside the box; their number."""
        with self._gizmo_lock:
            return self._preview()

    def _preview(self) -> int:
        if self.gizmo is None:
            return 0
        pts = self._track_points()
        R = quaternion_matrix(np.asarray(self.gizmo.wxyz, np.float64))
        inside = inside_box(pts, np.asarray(self.gizmo.position, np.float64), R, np.asarray(self.gui_size.value))
        self.gui_preview.content = preview_text(int(inside.sum()), len(pts))
        if inside.any():  # a child of the world, not of the gizmo: the points stay where they are
            self.scene.add_point_cloud("/cut_preview", pts[inside].astype(np.float32), PREVIEW_COLOUR, point_size=0.12,
                                       precision="float32", point_shading="flat")
        else:
            self.scene.remove_by_name("/cut_preview")
        return int(inside.sum())

    def place(self, centre: np.ndarray | None) -> None:
        """Move the gizmo to a newly shown track, sized to it."""
        with self._gizmo_lock:
            if self.gizmo is not None and centre is not None:
                self.scene.remove_by_name("/cut")
                self._add_gizmo(tuple(float(v) for v in centre))

    # ------------------------------------------------------------------ regions
    def _world_box(self) -> tuple[np.ndarray, np.ndarray]:
        """The gizmo's centre (3,) and rotation (3, 3) in the world frame."""
        T = self._pose()
        with self._gizmo_lock:
            c = np.asarray(self.gizmo.position, np.float64)
            R = quaternion_matrix(np.asarray(self.gizmo.wxyz, np.float64))
        return T[:3, :3] @ c + T[:3, 3], T[:3, :3] @ R

    def region(self, kind: str) -> dict[str, Any]:
        """The box or plane region (world frame) of the gizmo as the service's JSON."""
        centre, R = self._world_box()
        if kind == "box":
            return {"kind": "box", "center": centre.tolist(), "size": [float(v) for v in self.gui_size.value],
                    "wxyz": matrix_wxyz(R).tolist()}
        normal = R[:, 0]
        return {"kind": "halfspace", "normal": normal.tolist(), "offset": float(normal @ centre)}

    def cut(self, kind: str, this_frame_only: bool) -> None:
        if self.gizmo is None:
            self.gui_show_box.value = True  # shows the gizmo at the track; the operator places it, then cuts
            self._toggle_gizmo()
            return
        self._split(self.region(kind), this_frame_only)

    def cut_height(self) -> None:
        self._split({"kind": "height", "min_height": float(self.gui_height.value)}, False)

    def cut_predicted(self) -> None:
        """Split off the segments the newest model classifies as the chosen class (whole segments)."""
        model_id = self._model_id()
        if model_id is None:
            self._notify("No model", "Train a model (Jobs tab) before splitting by predicted class.", "yellow")
            return
        self._split({"kind": "predicted", "model_id": model_id, "class_name": str(self.gui_predicted_class.value)}, False)

    def _on_rect(self, event: viser.SceneRectSelectEvent) -> None:
        cam = event.client.camera
        clip_scene = clip_from_scene(np.asarray(cam.position), np.asarray(cam.wxyz), float(cam.fov), float(cam.aspect))
        clip_world = clip_scene @ np.linalg.inv(self._pose())
        region = {"kind": "lasso", "polygon": rect_polygon_ndc(event.screen_min, event.screen_max).tolist(),
                  "clip_from_world": clip_world.reshape(-1).tolist()}
        self._split(region, self.gui_screen_scope.value == SCOPES[1])

    # ------------------------------------------------------------------ merge
    def wants_click(self) -> bool:
        """A click in the scene merges (instead of opening the clicked track)."""
        return bool(self.gui_merge_click.value)

    def clicked(self, track_id: int) -> None:
        self.gui_merge_click.value = False  # one merge per tick: a stray second click opens instead
        self._merge(track_id)
