"""The side panels besides the review controls: progress, jobs (train / predict with a learning
curve) and anchors. Each panel takes the client's GUI API and an `ApiClient`, builds its handles
(`gui_*`) in the current GUI container, and refreshes on request; slow calls run in the caller's
thread pool, never in a GUI callback's critical path.
"""

from __future__ import annotations

import html
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import viser
import viser.uplot

from annotator_ui.client import ApiClient, ApiError
from annotator_ui.label_set import PAPER, ClassTable

JOB_BUTTONS = {"train": "Start training", "predict": "Start prediction"}
JOB_POLL_SECONDS = 1.0
ANCHORS_PATH = "/anchors"


class ProgressPanel:
    """The share of the sequence's points labelled, by source (GET /sequences/{id}/points-progress),
    then tracks reviewed / pending and samples labelled per class (GET /exports/stats)."""

    def __init__(self, gui: viser.GuiApi, api: ApiClient, sequence_id: Callable[[], int | None] = lambda: None) -> None:
        self.api = api
        self.sequence_id = sequence_id
        self.table = PAPER  # the classes of the shown sequence's label set
        self.gui_points = gui.add_markdown("")
        self.gui_points_bar = gui.add_progress_bar(0.0, color="blue")
        self.gui_summary = gui.add_markdown("Loading progress ...")
        self.gui_bar = gui.add_progress_bar(0.0, color="green")
        self.gui_classes = gui.add_html("")
        self.gui_refresh = gui.add_button("Refresh progress", icon=viser.Icon.REFRESH)
        self.gui_refresh.on_click(lambda _: self.refresh())
        self.last: dict[str, Any] | None = None

    def _refresh_points(self, seq: int | None) -> None:
        if seq is None or not self.api.has_route("get", "/sequences/{sequence_id}/points-progress"):
            return
        try:
            p = self.api.points_progress(seq)
        except ApiError as exc:
            self.gui_points.content = f"Points progress unavailable: {exc.detail}"
            return
        share = p["points_labelled"] / p["points_in_tracks"] if p["points_in_tracks"] else 0.0
        by = " · ".join(f"{src} {n:,}" for src, n in sorted(p["points_labelled_per_source"].items())) or "none yet"
        self.gui_points.content = (
            f"**Points labelled** {100 * share:.1f} % of the sequence's {p['points_in_tracks']:,} points in tracks "
            f"({p['points_labelled']:,}; by source: {by})  \n"
            f"pending {p['points_pending']:,} · discarded {p['points_discarded']:,} · accepted without class "
            f"{p['points_accepted_unlabelled']:,} · all points of the frames {p['points']:,}"
        )
        self.gui_points_bar.value = 100.0 * share

    def set_classes(self, table: ClassTable) -> None:
        """Count the samples of the classes of `table` (at the next refresh)."""
        self.table = table

    def refresh(self) -> dict[str, Any] | None:
        seq = self.sequence_id()
        self._refresh_points(seq)
        try:
            st = self.api.stats(seq)
        except ApiError as exc:
            self.gui_summary.content = f"Progress unavailable: {exc.detail}"
            return None
        self.last = st
        by = st.get("tracks_by_status", {})
        total = max(int(st.get("tracks", 0)), 0)
        reviewed = int(st.get("tracks_reviewed", 0))
        self.gui_summary.content = (
            f"**Tracks** {reviewed} reviewed / {by.get('pending', 0)} pending of {total}  \n"
            f"accepted {by.get('accepted', 0)} · discarded {by.get('discarded', 0)}  \n"
            f"**Samples** {st.get('samples_labelled', 0)} labelled of {st.get('samples', 0)} · "
            f"constraints verified {st.get('constraints_verified', 0)} of {st.get('constraints_automatic', 0)}"
        )
        self.gui_bar.value = 100.0 * reviewed / total if total else 0.0
        per = st.get("samples_labelled_per_class", {})
        top = max([1, *per.values()])
        rows = []
        for name in self.table.classes:
            n = int(per.get(name, 0))
            r, g, b = (int(v) for v in self.table.colours[name])
            rows.append(
                f'<div style="display:flex;align-items:center;gap:6px;font-size:12px;line-height:18px">'
                f'<span style="width:64px">{name}</span>'
                f'<span style="display:inline-block;height:10px;width:{max(1, int(120 * n / top))}px;'
                f'background:rgb({r},{g},{b})"></span><span>{n}</span></div>'
            )
        self.gui_classes.content = '<div style="padding:2px 4px">Samples per class' + "".join(rows) + "</div>"
        return st


def learning_curve(result: dict[str, Any] | None) -> dict[str, np.ndarray] | None:
    """Per-epoch series of a job result, or None when it has none.

    Accepts `history` / `epochs` / `metrics` as a list of per-epoch dicts (`{"epoch": 1, "loss":
    .., "val_f1": ..}`) or as a dict of equal-length lists. Returns {"epoch": x, name: y, ...} of
    the numeric series."""
    if not isinstance(result, dict):
        return None
    if isinstance(result.get("train_loss"), list) and result["train_loss"]:  # a model's stored metrics
        loss = result["train_loss"]
        val = result.get("val_f") if isinstance(result.get("val_f"), list) else []
        x = np.arange(1, len(loss) + 1, dtype=np.float64)
        out = {"epoch": x, "loss": np.asarray(loss, np.float64)}
        if len(val) == len(loss) and any(v is not None for v in val):
            out["val_f"] = np.asarray([np.nan if v is None else v for v in val], np.float64)
        return out
    for key in ("history", "epochs", "per_epoch", "metrics", "curve"):
        raw = result.get(key)
        if isinstance(raw, dict):
            for sub in ("history", "epochs", "per_epoch"):
                if isinstance(raw.get(sub), list | dict):
                    raw = raw[sub]
                    break
        if isinstance(raw, list) and raw and all(isinstance(r, dict) for r in raw):
            names = [k for k, v in raw[0].items() if isinstance(v, int | float) and not isinstance(v, bool)]
            cols = {k: [r.get(k) for r in raw] for k in names}
        elif isinstance(raw, dict) and raw and all(isinstance(v, list) for v in raw.values()):
            cols = {k: v for k, v in raw.items() if v and all(isinstance(x, int | float) for x in v)}
        else:
            continue
        n = min((len(v) for v in cols.values()), default=0)
        if n < 1:
            continue
        x = np.asarray(cols.pop("epoch", list(range(1, n + 1)))[:n], np.float64)
        series = {k: np.asarray([np.nan if v is None else v for v in vals[:n]], np.float64) for k, vals in cols.items()}
        series = {k: v for k, v in series.items() if k not in ("step", "steps")}
        if series:
            return {"epoch": x, **series}
    return None


class JobsPanel:
    """Start training or prediction (when the service has those job types), follow the job's
    progress, and plot its per-epoch metrics."""

    def __init__(self, gui: viser.GuiApi, api: ApiClient, notify: Callable[[str, str, str], None],
                 sequence_id: Callable[[], int | None], is_admin: bool = False) -> None:
        self.gui = gui
        self.api = api
        self.is_admin = is_admin
        self.notify = notify
        self.sequence_id = sequence_id
        self._closed = threading.Event()
        self._poll: threading.Thread | None = None
        self.job: dict[str, Any] | None = None
        self.types: dict[str, dict[str, Any]] = {}
        self.gui_types = gui.add_markdown("Loading job types ...")
        self.gui_buttons: dict[str, viser.GuiButtonHandle] = {}
        for name, label in JOB_BUTTONS.items():
            b = gui.add_button(label, disabled=True, icon=viser.Icon.PLAYER_PLAY)
            b.on_click(lambda _e, n=name: self.start(n))
            self.gui_buttons[name] = b
        self.gui_status = gui.add_markdown("No job started from this tab.")
        self.gui_bar = gui.add_progress_bar(0.0, animated=False)
        self.gui_cancel = gui.add_button("Cancel job", disabled=True, color="red")
        self.gui_cancel.on_click(lambda _: self.cancel())
        self.gui_curve: viser.GuiUplotHandle | None = None

    def close(self) -> None:
        self._closed.set()

    def refresh_types(self) -> None:
        try:
            self.types = {t["name"]: t for t in self.api.job_types()}
        except ApiError as exc:
            self.gui_types.content = f"Job types unavailable: {exc.detail}"
            return
        missing = [n for n in JOB_BUTTONS if n not in self.types]
        admin_only = [n for n in JOB_BUTTONS if n in self.types and self.types[n]["admin_only"] and not self.is_admin]
        for name, button in self.gui_buttons.items():
            button.disabled = name in missing or name in admin_only
        known = ", ".join(f"`{n}`" for n in sorted(self.types)) or "none"
        text = f"Job types of this service: {known}."
        if missing:
            text += " Not available here: " + ", ".join(f"`{n}`" for n in missing) + " (their buttons are disabled)."
        if admin_only:
            text += " " + ", ".join(f"`{n}`" for n in admin_only) + " need the admin role (sign in with an admin token)."
        self.gui_types.content = text

    def _params(self, name: str) -> dict[str, Any]:
        """Defaults, plus the shown sequence when the type's params take a `sequence_id`."""
        props = self.types.get(name, {}).get("params_schema", {}).get("properties", {})
        params: dict[str, Any] = {}
        seq = self.sequence_id()
        if seq is not None and "sequence_id" in props:
            params["sequence_id"] = seq
        if seq is not None and "sequence_ids" in props:  # train: the labels of the shown sequence
            params["sequence_ids"] = [seq]
        if "model_id" in props:  # predict: the newest model
            try:
                models = self.api.get("/models", limit=1)
            except ApiError:
                models = []
            if models:
                params["model_id"] = models[0]["id"]
        return params

    def start(self, name: str) -> dict[str, Any] | None:
        try:
            job = self.api.create_job(name, self._params(name))
        except ApiError as exc:
            self.notify("Job not started", f"{name}: {exc.detail}", "red")
            return None
        self.job = job
        self._show(job)
        self.notify("Job queued", f"{name} job #{job['id']} is queued", "blue")
        if self._poll is None or not self._poll.is_alive():
            self._poll = threading.Thread(target=self._follow, name=f"job-poll-{job['id']}", daemon=True)
            self._poll.start()
        return job

    def cancel(self) -> None:
        if self.job is None:
            return
        try:
            self._show(self.api.cancel_job(self.job["id"]))
        except ApiError as exc:
            self.notify("Cancel failed", exc.detail, "red")

    def _follow(self) -> None:
        while not self._closed.is_set() and self.job is not None:
            try:
                job = self.api.job(self.job["id"])
            except ApiError:
                time.sleep(JOB_POLL_SECONDS)
                continue
            self._show(job)  # the bar and status first: whoever reads self.job sees them drawn
            self.job = job
            if job["status"] in ("succeeded", "failed", "cancelled"):
                model_id = (job.get("result") or {}).get("model_id")
                if job["status"] == "succeeded" and model_id:
                    try:  # the finished run's full per-epoch metrics live with its model
                        curve = learning_curve((self.api.get(f"/models/{model_id}") or {}).get("metrics"))
                    except ApiError:
                        curve = None
                    if curve is not None:
                        self._plot(curve)
                colour = "green" if job["status"] == "succeeded" else "red"
                self.notify(f"Job {job['status']}", f"{job['type']} job #{job['id']}: {job.get('message') or job['status']}", colour)
                return
            self._closed.wait(JOB_POLL_SECONDS)

    def _show(self, job: dict[str, Any]) -> None:
        pct = 100.0 * float(job.get("progress") or 0.0)
        self.gui_bar.value = min(max(pct, 0.0), 100.0)
        self.gui_bar.animated = job["status"] in ("queued", "running")
        msg = html.escape(job.get("message") or "")
        err = job.get("error")
        self.gui_status.content = (
            f"**{job['type']}** job #{job['id']}: {job['status']} ({pct:.0f} %)"
            + (f"  \n{msg}" if msg else "")
            + (f"  \nerror: {html.escape(str(err))[:300]}" if err else "")
        )
        self.gui_cancel.disabled = job["status"] not in ("queued", "running")
        curve = learning_curve(job.get("result"))
        if curve is not None:
            self._plot(curve)

    def _plot(self, curve: dict[str, np.ndarray]) -> None:
        names = [k for k in curve if k != "epoch"]
        palette = ["#e8590c", "#1c7ed6", "#2f9e44", "#ae3ec9", "#f59f00", "#0ca678", "#c92a2a"]
        data = tuple(curve[k] for k in ("epoch", *names))
        series = (viser.uplot.Series(label="epoch"),) + tuple(
            viser.uplot.Series(label=k, stroke=palette[i % len(palette)], width=2) for i, k in enumerate(names)
        )
        if self.gui_curve is not None and len(self.gui_curve.series) == len(series):
            self.gui_curve.data = data
            return
        if self.gui_curve is not None:
            self.gui_curve.remove()
        self.gui_curve = self.gui.add_uplot(data, series, title="Learning curve", aspect=1.4)


class _RowsPanel:
    """A panel listing one page of an API resource's waiting rows (anchor proposals, stitches): a
    status line, the subclass's buttons, a refresh button and a folder of rows that each refresh
    rebuilds. The subclass's `_refresh` reads the page and draws it."""

    PAGE = 8
    # what it lists (the status line while it looks), its refresh button, its rows' folder
    NAMES = ("rows", "Refresh", "Rows")

    def __init__(self, gui: viser.GuiApi, api: ApiClient, notify: Callable[[str, str, str], None],
                 sequence_id: Callable[[], int | None], open_track: Callable[[int], None]) -> None:
        what, refresh_label, rows_title = self.NAMES
        self.gui = gui
        self.api = api
        self.notify = notify
        self.sequence_id = sequence_id
        self.open_track = open_track
        self.available = False
        self.gui_status = gui.add_markdown(f"Checking for {what} ...")
        self._add_buttons()
        self.gui_refresh = gui.add_button(refresh_label, icon=viser.Icon.REFRESH, disabled=True)
        self.gui_refresh.on_click(lambda _: self.refresh())
        # rows are added from background threads: viser puts a handle in the container of the
        # thread's `with` block, so without this folder they landed under every tab
        self.gui_rows = gui.add_folder(rows_title, expand_by_default=True)
        self._items: list[Any] = []
        # a refresh runs from the tab's background work and from buttons at the same time (and
        # after quick successive actions); viser lets one thread at a time into the rows' folder
        self._lock = threading.Lock()

    def _add_buttons(self) -> None:
        """The panel's own buttons, above Refresh (none here)."""

    def refresh(self) -> None:
        with self._lock:
            self._refresh()

    def _refresh(self) -> None:
        raise NotImplementedError

    def _clear_rows(self) -> None:
        for h in self._items:
            h.remove()
        self._items = []


class AnchorsPanel(_RowsPanel):
    """Anchor proposals (issue 7's `/anchors`): the waiting proposals of the shown sequence, each
    with its sample and proposed class; the operator confirms, corrects (another class) or rejects
    it, or opens its track in the 3D view. Without that API the panel says so and stays disabled."""

    NAMES = ("anchor proposals", "Refresh anchors", "Waiting proposals")
    table: ClassTable = PAPER  # the classes of the shown sequence's label set (its rows' dropdowns)

    def set_classes(self, table: ClassTable) -> None:
        """Offer the classes of `table` in the rows drawn from now on."""
        self.table = table

    def _add_buttons(self) -> None:
        self.gui_propose = self.gui.add_button("Propose anchors", icon=viser.Icon.ANCHOR, disabled=True)
        self.gui_propose.on_click(lambda _: self.propose())

    def _refresh(self) -> None:
        self.available = self.api.has_route("get", ANCHORS_PATH)
        self.gui_refresh.disabled = not self.available
        if not self.available:
            self.gui_propose.disabled = True
            self.gui_status.content = (
                "**No anchor proposals.** This track service has no anchor proposals API, so there is "
                "nothing to confirm here."
            )
            return
        try:
            types = {t["name"] for t in self.api.job_types()}
            seq = self.sequence_id()
            params = {"status": "proposed", "limit": self.PAGE}
            if seq is not None:
                params["sequence_id"] = seq
            body = self.api.get(ANCHORS_PATH, **params)
        except ApiError as exc:
            self.gui_status.content = f"Anchor proposals unavailable: {exc.detail}"
            return
        self.gui_propose.disabled = "propose_anchors" not in types or self.sequence_id() is None
        self._render(body.get("items", []), int(body.get("total", 0)))

    def propose(self) -> None:
        seq = self.sequence_id()
        if seq is None:
            return
        try:
            job = self.api.create_job("propose_anchors", {"sequence_id": seq})
        except ApiError as exc:
            self.notify("Anchors not proposed", exc.detail, "red")
            return
        self.notify("Anchor proposal queued", f"job #{job['id']}; refresh when it has finished", "blue")

    def _render(self, items: list[dict[str, Any]], total: int) -> None:
        self._clear_rows()
        if not items:
            self.gui_status.content = (
                "**No anchor proposals** are waiting. A trained model proposes them (Propose anchors)."
            )
            return
        self.gui_status.content = f"**{total}** anchor proposals waiting; the first {len(items)}:"
        with self.gui_rows:
            for item in items:
                self._items.extend(self._anchor_row(item))

    def _anchor_row(self, item: dict[str, Any]) -> list[Any]:
        from annotator_ui.samples import sample_image

        handles: list[Any] = []
        cls = item.get("proposed_class")
        title = (f"#{item['id']} {cls or '?'} · {item.get('level')} · track {item['track_id']}"
                 + (f" · frame {item['frame_index']}" if item.get("frame_index") is not None else ""))
        url = item.get("sample_url")
        image = None
        if url:
            try:
                image = sample_image(self.api.sample_png(url))
            except ApiError:
                image = None
        handles.append(self.gui.add_image(image, label=title, format="png") if image is not None
                       else self.gui.add_markdown(title))
        classes = self.table.classes
        other = self.table.fallback if self.table.fallback in classes else classes[0]
        choice = self.gui.add_dropdown(f"Class #{item['id']}", classes, initial_value=cls if cls in classes else other)
        answer = self.gui.add_button_group(f"Anchor #{item['id']}", ("Confirm", "Reject", "Show track"))
        answer.on_click(lambda e, it=item, ch=choice: self._answer(it, e.target.value, ch.value))
        return [*handles, choice, answer]

    def _answer(self, item: dict[str, Any], what: str, class_name: str) -> None:
        if what == "Show track":
            self.open_track(int(item["track_id"]))
            return
        try:
            if what == "Reject":
                self.api.post(f"{ANCHORS_PATH}/{item['id']}/reject")
            elif class_name == item.get("proposed_class"):
                self.api.post(f"{ANCHORS_PATH}/{item['id']}/confirm")
            else:
                self.api.post(f"{ANCHORS_PATH}/{item['id']}/correct", {"label": class_name})
        except ApiError as exc:
            self.notify("Anchor answer not saved", exc.detail, "red")
        self.refresh()


STITCHES_PATH = "/stitches"


class StitchesPanel(_RowsPanel):
    """Stitches (`/stitches`): two tracks joined by fragment links, pieces of one object. The
    panel lists the pending stitches of the shown track (else of the shown sequence), most links
    first; the operator confirms (one object: its fragment pairs become constraints once both
    tracks are accepted), rejects, merges the two tracks into one, or opens either track in the
    3D view. The tab refreshes it after every action and track change, so its rows are always
    those of the shown track. Without that API the panel says so and stays disabled."""

    NAMES = ("stitches", "Refresh stitches", "Pending stitches")

    def __init__(self, gui: viser.GuiApi, api: ApiClient, notify: Callable[[str, str, str], None],
                 sequence_id: Callable[[], int | None], track_id: Callable[[], int | None],
                 open_track: Callable[[int], None], merge: Callable[[int, int], None] | None = None) -> None:
        self.merge = merge
        self.track_id = track_id
        super().__init__(gui, api, notify, sequence_id, open_track)
        self._shown: tuple[Any, ...] | None = None

    def _refresh(self) -> None:
        self.available = self.api.has_route("get", STITCHES_PATH)
        self.gui_refresh.disabled = not self.available
        if not self.available:
            self.gui_status.content = "**No stitches.** This track service has no stitches API."
            return
        track, seq = self.track_id(), self.sequence_id()
        params: dict[str, Any] = {"status": "pending", "limit": self.PAGE}
        if track is not None:
            params["track_id"] = track
        elif seq is not None:
            params["sequence_id"] = seq
        try:
            body = self.api.get(STITCHES_PATH, **params)
        except ApiError as exc:
            self.gui_status.content = f"Stitches unavailable: {exc.detail}"
            return
        self._render(body.get("items", []), int(body.get("total", 0)), track)

    def _render(self, items: list[dict[str, Any]], total: int, track: int | None) -> None:
        key = (track, total, tuple((i["id"], i["version"]) for i in items))
        if key == self._shown:
            return  # the same rows: rebuilding them would only make the browser lay the panel out again
        self._shown = key
        self._clear_rows()
        where = f"of track {track}" if track is not None else "of this sequence"
        if not items:
            self.gui_status.content = f"**No pending stitches** {where}."
            return
        buttons = ("One object", "Different", *(("Merge",) if self.merge else ()))
        with self.gui_rows:
            for item in items:
                a, b = int(item["track_a_id"]), int(item["track_b_id"])
                self._items.append(self.gui.add_markdown(
                    f"#{item['id']} · track {a} ↔ track {b} · {item['links']} links · share {item['share']:.2f}"))
                group = self.gui.add_button_group(f"Stitch #{item['id']}", (*buttons, f"Show {a}", f"Show {b}"))
                group.on_click(lambda e, it=item: self._decide(it, e.target.value))
                self._items.append(group)
        self.gui_status.content = f"**{total}** pending stitches {where}; the first {len(items)}:"  # rows first

    def _decide(self, item: dict[str, Any], what: str) -> None:
        if what.startswith("Show "):
            self.open_track(int(what.split()[1]))
            return
        if what == "Merge" and self.merge is not None:
            self.merge(int(item["track_a_id"]), int(item["track_b_id"]))
            return
        action = "confirm" if what == "One object" else "reject"
        try:
            self.api.post(f"{STITCHES_PATH}/{item['id']}/{action}", {"version": int(item["version"])})
        except ApiError as exc:
            self.notify("Stitch decision not saved", exc.detail, "red")
        self.refresh()
