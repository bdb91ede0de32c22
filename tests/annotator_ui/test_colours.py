"""Colour modes, highlight fading and the legend."""

from __future__ import annotations

import numpy as np

from annotator_ui.colours import (
    DISCARDED,
    GROUND,
    NO_PREDICTION,
    PENDING,
    UNTRACKED,
    fade,
    legend_html,
    point_colours,
    predicted_colour,
    track_hues,
)
from pipeline.classes import CLASS_COLOURS

SEG = np.array([-1, 0, 1, 1, 2, 2], np.int32)
TRK = np.array([0, 0, 7, 7, 9, 9], np.int64)


def test_colours_track_mode_one_colour_per_track():
    c = point_colours(SEG, TRK, "track")
    assert (c[0] == GROUND).all() and (c[1] == UNTRACKED).all()
    assert (c[2] == c[3]).all() and not (c[2] == c[4]).all()
    assert len({tuple(v) for v in track_hues(np.arange(1, 50))}) == 49  # distinct hues for neighbours


def test_colours_class_mode_uses_labels_of_accepted_tracks():
    tracks = {7: {"status": "accepted", "label": "car"}, 9: {"status": "discarded", "label": None}}
    c = point_colours(SEG, TRK, "class", tracks)
    assert tuple(c[2]) == CLASS_COLOURS["car"] and (c[4] == DISCARDED).all()
    c = point_colours(SEG, TRK, "class", {7: {"status": "pending", "label": None}})
    assert (c[2] == PENDING).all() and (c[4] == PENDING).all()  # unknown to the map: pending


def test_colours_predicted_mode_greys_out_with_low_confidence():
    sure = predicted_colour({"predicted_class": "person", "predicted_confidence": 1.0})
    unsure = predicted_colour({"predicted_class": "person", "predicted_confidence": 0.1})
    assert tuple(sure) == CLASS_COLOURS["person"]
    assert abs(int(unsure[0]) - int(NO_PREDICTION[0])) < abs(int(sure[0]) - int(NO_PREDICTION[0]))
    assert (predicted_colour({"predicted_class": None}) == NO_PREDICTION).all()


def test_colours_fade_darkens_all_but_the_highlight():
    c = point_colours(SEG, TRK, "track")
    f = fade(c, TRK == 7)
    assert (f[2:4] == c[2:4]).all() and (f[4].astype(int) < c[4].astype(int)).all()


def test_colours_legend_lists_every_class_in_class_mode():
    html = legend_html("class")
    assert all(name in html for name in CLASS_COLOURS) and "discarded" in html
