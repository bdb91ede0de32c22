"""Point colours of the three colour modes, the highlight of the reviewed track, and the legend.

All functions are vectorised over the frame's points; colours are (N, 3) uint8 RGB.

Modes:
  - `track`:     one hue per track id (golden-ratio hues, stable across frames);
  - `class`:     the track's class label (accepted tracks), grey while unlabelled, dark red when
                 discarded (class colours: the sequence's label set, `annotator_ui.label_set`);
  - `predicted`: the model's predicted class, blended towards grey as its confidence falls.
Ground and points without a track are dark grey in every mode.
"""

from __future__ import annotations

import html
from collections.abc import Mapping
from typing import Any, Literal

import numpy as np

from annotator_ui.label_set import PAPER, ClassTable

ColourMode = Literal["track", "class", "predicted"]
COLOUR_MODES: tuple[ColourMode, ...] = ("track", "class", "predicted")

GROUND = np.array([70, 70, 70], np.uint8)
UNTRACKED = np.array([110, 110, 110], np.uint8)
PENDING = np.array([175, 175, 175], np.uint8)
DISCARDED = np.array([120, 40, 40], np.uint8)
NO_PREDICTION = np.array([150, 150, 150], np.uint8)
HIGHLIGHT_FADE = 0.5  # other points keep this much of their colour while a track is highlighted


def track_hues(track_ids: np.ndarray) -> np.ndarray:
    """(N,) int track ids -> (N, 3) uint8: a saturated colour per id (golden-ratio hue steps)."""
    h = (np.asarray(track_ids, np.int64) * 0.6180339887498949) % 1.0
    s, v = 0.75, 0.95
    i = np.floor(h * 6.0).astype(np.int64) % 6
    f = h * 6.0 - np.floor(h * 6.0)
    p, q, t = v * (1 - s), v * (1 - f * s), v * (1 - (1 - f) * s)
    vv = np.full_like(h, v)
    pp = np.full_like(h, p)
    r = np.choose(i, [vv, q, pp, pp, t, vv])
    g = np.choose(i, [t, vv, vv, q, pp, pp])
    b = np.choose(i, [pp, pp, t, vv, vv, q])
    return (np.stack([r, g, b], axis=1) * 255.0 + 0.5).astype(np.uint8)


def class_colour(track: Mapping[str, Any], table: ClassTable = PAPER) -> np.ndarray:
    """Colour of a track (TrackPublic dict) in `class` mode, in the colours of `table`."""
    if track.get("status") == "discarded":
        return DISCARDED
    label = track.get("label")
    if track.get("status") == "accepted" and label in table.colours:
        return table.colours[label]
    return PENDING


def predicted_colour(track: Mapping[str, Any], table: ClassTable = PAPER) -> np.ndarray:
    """Colour of a track in `predicted` mode: class colour blended to grey by (1 - confidence)."""
    cls = track.get("predicted_class")
    if cls not in table.colours:
        return NO_PREDICTION
    conf = track.get("predicted_confidence")
    c = 1.0 if conf is None else float(np.clip(conf, 0.0, 1.0))
    mixed = NO_PREDICTION.astype(np.float32) * (1.0 - c) + table.colours[cls].astype(np.float32) * c
    return (mixed + 0.5).astype(np.uint8)


def point_colours(
    segment: np.ndarray,
    track: np.ndarray,
    mode: ColourMode,
    tracks: Mapping[int, Mapping[str, Any]] | None = None,
    table: ClassTable = PAPER,
) -> np.ndarray:
    """(N,) segment, (N,) track ids -> (N, 3) uint8 colours in `mode`.

    `tracks` maps track id -> TrackPublic dict (needed by `class` and `predicted`), whose classes
    take the colours of `table`."""
    n = len(segment)
    assert track.shape == (n,), (track.shape, n)
    # one key per point (track id, 0 = segment without track, -1 = ground), colours per unique key,
    # then a single gather: the frame's few hundred tracks are coloured, not its 70k points
    key = np.where(track > 0, track, np.where(segment >= 0, 0, -1))
    uniq, inverse = np.unique(key, return_inverse=True)
    lut = np.empty((len(uniq), 3), np.uint8)
    lut[uniq == -1] = GROUND
    lut[uniq == 0] = UNTRACKED
    tracked = uniq > 0
    if mode == "track":
        lut[tracked] = track_hues(uniq[tracked])
    else:
        tracks = tracks or {}
        fn = class_colour if mode == "class" else predicted_colour
        default = PENDING if mode == "class" else NO_PREDICTION
        for k in np.flatnonzero(tracked).tolist():  # one entry per track of the frame, not per point
            t = tracks.get(int(uniq[k]))
            lut[k] = default if t is None else fn(t, table)
    return lut[inverse.reshape(-1)]


def fade(colours: np.ndarray, keep: np.ndarray, factor: float = HIGHLIGHT_FADE) -> np.ndarray:
    """Darken every colour outside the (N,) bool mask `keep` (the highlighted points)."""
    scale = int(round(factor * 256))
    out = ((colours.astype(np.uint16) * scale) >> 8).astype(np.uint8)
    out[keep] = colours[keep]
    return out


def legend_entries(mode: ColourMode, table: ClassTable = PAPER) -> list[tuple[str, tuple[int, int, int]]]:
    """(label, RGB) rows of the legend of `mode` (class rows: those of `table`)."""
    classes = [(name, tuple(int(v) for v in table.colours[name])) for name in table.classes]
    common = [("ground", tuple(int(v) for v in GROUND)), ("no track", tuple(int(v) for v in UNTRACKED)),
              ("the reviewed track: outline (its points in height or intensity colours)", (255, 215, 0)),
              ("track path (kept / cut / this frame)", (255, 140, 0))]
    if mode == "track":
        return [("one colour per track", (230, 120, 60)), *common]
    if mode == "class":
        return [*classes, ("pending", tuple(int(v) for v in PENDING)),
                ("discarded", tuple(int(v) for v in DISCARDED)), *common]
    return [*classes, ("no prediction", tuple(int(v) for v in NO_PREDICTION)), *common]


def legend_html(mode: ColourMode, table: ClassTable = PAPER) -> str:
    """The legend of `mode` as small HTML (coloured squares and names)."""
    rows = []
    for label, (r, g, b) in legend_entries(mode, table):
        rows.append(
            f'<div style="display:flex;align-items:center;gap:6px;font-size:12px;line-height:18px">'
            f'<span style="display:inline-block;width:12px;height:12px;border-radius:2px;'
            f'background:rgb({r},{g},{b});border:1px solid #555"></span>{html.escape(label)}</div>'
        )
    note = {
        "track": "Colour by track.",
        "class": "Colour by the operators' class labels.",
        "predicted": "Colour by the model's predicted class; greyer = less confident.",
    }[mode]
    return f'<div style="padding:2px 4px"><div style="font-size:12px;margin-bottom:4px">{note}</div>{"".join(rows)}</div>'
