"""The Model tab: bulk accept of the model-in-the-loop's confident predictions.

The operator picks a class and a confidence, previews (how many pending tracks and points would be
accepted, how often such predictions were right on held-out reviewed tracks, the largest of them
to open in the 3D view), then accepts them all in one action, which sends the previewed count so
that a retrain in between is refused rather than accepted unseen. The sequence's bulk accepts are
listed; the newest can be undone in one action.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

import viser

from annotator_ui.client import ApiClient, ApiError
from annotator_ui.label_set import PAPER, ClassTable


def preview_text(p: dict[str, Any]) -> str:
    """The preview as the operator reads it."""
    if not p["tracks"]:
        return f"No pending track is predicted **{p['class_name']}** at {100 * p['min_confidence']:.0f} % or more."
    held = p.get("held_out_precision")
    check = (f"right on **{100 * held:.1f} %** of {p['held_out_tracks']} held-out reviewed tracks"
             if held is not None else "no held-out reviewed track to check it on yet")
    if p.get("min_points"):
        check += f" (tracks under {p['min_points']:,} points, smaller than any of those, are left out)"
    return (f"**{p['tracks']}** pending tracks ({p['points']:,} points) predicted **{p['class_name']}** at "
            f"{100 * p['min_confidence']:.0f} % or more (mean {100 * (p['confidence_mean'] or 0):.0f} %); "
            f"such predictions were {check}.")


class BulkPanel:
    """Bulk accept with its preview, and the list of bulk accepts with undo."""

    def __init__(self, gui: viser.GuiApi, api: ApiClient, notify: Callable[[str, str, str], None],
                 sequence_id: Callable[[], int | None], open_track: Callable[[int], None]) -> None:
        self.api, self.notify, self.sequence_id, self.open_track = api, notify, sequence_id, open_track
        self.gui_class = gui.add_dropdown("Predicted class", PAPER.classes, initial_value=PAPER.classes[0])
        self.gui_confidence = gui.add_slider("Min confidence", min=0.5, max=1.0, step=0.01, initial_value=0.9)
        self.gui_preview = gui.add_button("Preview", icon=viser.Icon.EYE)
        self.gui_summary = gui.add_markdown("Preview to see what a bulk accept would label.")
        self.gui_show = gui.add_button("Show the largest", icon=viser.Icon.SEARCH, disabled=True)
        self.gui_accept = gui.add_button("Accept all", color="green", icon=viser.Icon.CHECKS, disabled=True)
        self.gui_history = gui.add_markdown("")
        self.gui_undo = gui.add_button("Undo the newest bulk accept", icon=viser.Icon.ARROW_BACK_UP, disabled=True)
        self.previewed: dict[str, Any] | None = None
        self.newest: dict[str, Any] | None = None
        self._lock = threading.Lock()
        self.gui_preview.on_click(lambda _: self.preview())
        self.gui_accept.on_click(lambda _: self.accept())
        self.gui_show.on_click(lambda _: self._show_largest())
        self.gui_undo.on_click(lambda _: self.undo())
        for handle in (self.gui_class, self.gui_confidence):
            handle.on_update(lambda _: self._stale())

    def _stale(self) -> None:
        self.previewed = None
        self.gui_accept.disabled = self.gui_show.disabled = True
        self.gui_accept.label = "Accept all"

    def preview(self) -> dict[str, Any] | None:
        seq = self.sequence_id()
        if seq is None:
            self.gui_summary.content = "No sequence is ready."
            return None
        params = {"class_name": str(self.gui_class.value), "min_confidence": float(self.gui_confidence.value)}
        try:
            p = self.api.get(f"/sequences/{seq}/bulk-accept/preview", **params)
        except ApiError as exc:
            self.gui_summary.content = f"Preview unavailable: {exc.detail}"
            return None
        with self._lock:
            self.previewed = p | {"sequence_id": seq}
            self.gui_summary.content = preview_text(p)
            self.gui_accept.label = f"Accept {p['tracks']} tracks"
            self.gui_accept.disabled = p["tracks"] == 0
            self.gui_show.disabled = not p["largest_track_ids"]
        return p

    def _show_largest(self) -> None:
        if self.previewed and self.previewed["largest_track_ids"]:
            self.open_track(int(self.previewed["largest_track_ids"][0]))

    def accept(self) -> dict[str, Any] | None:
        p = self.previewed
        if p is None or not p["tracks"]:
            return None
        body = {"class_name": p["class_name"], "min_confidence": p["min_confidence"], "expected_tracks": p["tracks"]}
        try:
            bulk = self.api.post(f"/sequences/{p['sequence_id']}/bulk-accept", body)
        except ApiError as exc:
            self.notify("Bulk accept refused", exc.detail, "yellow")
            self.preview()
            return None
        self.notify("Bulk accept", f"{bulk['n_tracks']} tracks accepted as {bulk['class_name']}", "green")
        self._stale()
        self.refresh()
        return bulk

    def set_classes(self, table: ClassTable) -> None:
        """Offer the classes of `table` (the shown sequence's label set)."""
        table.set_dropdown(self.gui_class)

    def refresh(self) -> None:
        seq = self.sequence_id()
        if seq is None:
            return
        try:
            bulks = self.api.get(f"/sequences/{seq}/bulk-actions")
        except ApiError:
            return
        live = [b for b in bulks if b["undone_at"] is None]
        self.newest = live[-1] if live else None
        self.gui_undo.disabled = self.newest is None
        rows = [f"- #{b['id']}: {b['n_tracks']} {b['class_name']} tracks at {100 * b['min_confidence']:.0f} %"
                + (" (undone)" if b["undone_at"] else "") for b in bulks[-8:]]
        self.gui_history.content = "**Bulk accepts**  \n" + "\n".join(rows) if rows else ""

    def undo(self) -> None:
        if self.newest is None:
            return
        try:
            self.api.post(f"/bulk-actions/{self.newest['id']}/undo")
        except ApiError as exc:
            self.notify("Undo refused", exc.detail, "yellow")
        self.refresh()
