"""The Review tab of a tab's GUI: the sequence picker, the key help, what the shown track is, the
frame slider, the sample, the action buttons (from `annotator_ui.actions`), opening a track by id,
colouring, and the track views. Texts only; the tab does the work through injected callbacks."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import viser

from annotator_ui.actions import (
    ACTIONS,
    AFTER_CLASSES,
    BEFORE_CLASSES,
    Action,
    actions_for,
    class_actions,
    key_help,
    review_action,
)
from annotator_ui.client import ApiClient, ApiError
from annotator_ui.colours import COLOUR_MODES, legend_html
from annotator_ui.label_set import PAPER, ClassTable
from annotator_ui.samples import blank_image
from annotator_ui.track_views_panel import TrackViewsPanel


def sequence_label(seq: dict[str, Any]) -> str:
    return f"{seq['name']} (#{seq['id']})"


class ReviewPanel:
    def __init__(self, gui: viser.GuiApi, press: Callable[[Action], None], add_playback: Callable[[], Any],
                 redraw: Callable[[], None], follow_camera: bool) -> None:
        self.gui_sequence = gui.add_dropdown("Sequence", ("(loading)",), initial_value="(loading)")
        self.gui_keys = gui.add_markdown(key_help())  # first: visible without scrolling
        self.gui_track = gui.add_markdown("Loading the review queue ...")
        self.playback = add_playback()
        self.gui_sample = gui.add_image(blank_image(), label="Sample (height · range · intensity · mask)", format="png")
        self.gui_route = gui.add_image(blank_image(), label="Route (grey) · seen from (orange) · track (white)", format="png")
        self.gui_predicted = gui.add_markdown("Model: no prediction for this track")
        self.buttons: dict[str, Any] = {}  # button text or group label -> handle
        self.gui = gui
        self.press = press
        self.actions: tuple[Action, ...] = ACTIONS
        self.table = PAPER
        self._add_buttons(BEFORE_CLASSES)
        self._class_groups = self._add_buttons(class_actions(self.table))
        after = self._add_buttons(AFTER_CLASSES)[0]
        # class groups of another label set go between the two (GUI order is a float)
        self._between = (self._class_groups[0].order - 0.5, after.order)
        self.gui_goto = gui.add_text("Open track #", initial_value="", hint="review a track by its id")
        self.gui_open = gui.add_button("Open track", icon=viser.Icon.SEARCH)
        self.gui_colour = gui.add_dropdown("Colour by", COLOUR_MODES, initial_value="track")
        self.gui_follow = gui.add_checkbox("Camera follows track", follow_camera)
        self.gui_legend = gui.add_html(legend_html("track"))
        with gui.add_folder("Track views"):
            self.views = TrackViewsPanel(gui, redraw)

    def _add_buttons(self, rows: tuple[Action, ...], order: Callable[[int], float] | None = None) -> list[Any]:
        """A button per row, one button group per `group` (in row order; `order(j)`: the GUI order
        of the j-th handle); returns the handles."""
        groups: dict[str, list[Action]] = {}
        for a in rows:
            if a.button is not None and a.group is not None:
                groups.setdefault(a.group, []).append(a)
        added: list[Any] = []
        for a in rows:
            if a.button is None:
                continue
            if a.group is None:
                h = self.gui.add_button(a.button, color=a.colour, icon=getattr(viser.Icon, a.icon) if a.icon else None)  # type: ignore[arg-type]

                async def clicked(_e: Any, a: Action = a) -> None:  # async: runs as the click arrives
                    self.press(a)

                h.on_click(clicked)
                self.buttons[a.button] = h
                added.append(h)
            elif a.group not in self.buttons:
                kw = {} if order is None else {"order": order(len(added))}
                g = self.gui.add_button_group(a.group, tuple(x.button for x in groups[a.group] if x.button), **kw)

                async def grouped(e: Any) -> None:
                    self.press(review_action(e.target.value, self.actions))

                g.on_click(grouped)
                self.buttons[a.group] = g
                added.append(g)
        return added

    def show_classes(self, table: ClassTable) -> tuple[Action, ...]:
        """Replace the class buttons and the key help with those of `table` (the label set of the
        shown track's sequence); returns the tab's rows now."""
        if table == self.table:
            return self.actions
        for g in self._class_groups:
            self.buttons = {k: h for k, h in self.buttons.items() if h is not g}
            g.remove()
        rows = class_actions(table)
        n_groups = len({a.group for a in rows})
        lo, hi = self._between
        self._class_groups = self._add_buttons(rows, lambda j: lo + (hi - lo) * (j + 1) / (n_groups + 1))
        self.table, self.actions = table, actions_for(table)
        self.gui_keys.content = key_help(self.actions)
        return self.actions

    def set_sequences(self, seqs: list[dict[str, Any]], chosen: int | None) -> None:
        options = tuple(sequence_label(s) for s in seqs) or ("(no sequence)",)
        self.gui_sequence.options = options
        pick = next((sequence_label(s) for s in seqs if s["id"] == chosen), options[0])
        self.gui_sequence.value = pick

    def chosen_sequence(self) -> int | None:
        text = self.gui_sequence.value
        return int(text.rsplit("#", 1)[1].rstrip(")")) if "#" in text else None


def track_info(t: dict[str, Any], frame_index: int, from_queue: bool, sequence: str, drawn_points: int) -> str:
    pred = ""
    if t.get("predicted_class"):
        conf = t.get("predicted_confidence")
        pred = f" · predicted **{t['predicted_class']}**" + (f" ({100 * conf:.0f} %)" if conf is not None else "")
    where = "queue" if from_queue else "picked"
    kept = t["keep_start"] <= frame_index <= t["keep_end"]
    seg = next((s for s in t["segments"] if s["frame_index"] == frame_index), None)
    rng = f" · range **{seg['range']:.1f} m**" if seg is not None and seg.get("range") is not None else ""
    return (
        f"**Track {t['id']}** ({where}) · {t['status']}" + (f" · **{t['label']}**" if t.get("label") else "")
        + pred + "  \n"
        f"sequence **{sequence}** · frames {t['first_frame']}-{t['last_frame']} · kept {t['keep_start']}-{t['keep_end']} · "
        f"{t['n_samples']} samples · {t['n_points']} points · v{t['version']}  \n"
        f"frame **{frame_index}**" + ("" if kept else " (outside the kept range)")
        + f" · {drawn_points} points drawn" + rng
    )


def predicted_info(t: dict[str, Any], actions: tuple[Action, ...] = ACTIONS) -> str:
    """The model's class and confidence, shown beside the class buttons, with the class's key
    among the tab's `actions`."""
    if not t.get("predicted_class"):
        return "Model: no prediction for this track"
    conf = t.get("predicted_confidence")
    key = next((a.key for a in actions if a.review == "label" and a.arg == t["predicted_class"]), None)
    return (f"Model: **{t['predicted_class']}**" + (f" ({100 * conf:.0f} %)" if conf is not None else "")
            + (f" · key **{key}**" if key else ""))


def empty_queue_message(api: ApiClient, sequence_id: int | None = None) -> str:
    """Why no track is shown: a failed or empty ingest says so, else everything is reviewed."""
    try:
        seqs = api.sequences()
        stats = api.stats(sequence_id)
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
