"""The tab's classes are those of the shown track's sequence's label set, read from the service:
class buttons, hotkeys, colours and dropdowns change when a track of a sequence of another set is
shown (headless client; fixtures in conftest.py)."""

from __future__ import annotations

from annotator_ui.client import ApiClient
from annotator_ui.label_set import PAPER, ClassTable, LabelSets
from pipeline.classes import SAMPLE_CLASSES
from tests.annotator_ui.test_viewer import wait_until

CAMPUS = {"name": "campus", "fallback": None, "classes": [
    {"name": "walker", "colour": [255, 0, 0], "key": "q", "ground": False},
    {"name": "cart", "colour": [0, 0, 255], "key": "A", "ground": False},  # A accepts: a button only
    {"name": "dog", "colour": [0, 255, 0], "key": None, "ground": False},
    {"name": "lawn", "colour": [0, 200, 0], "key": "4", "ground": True},
]}


def _command(tab, label):  # noqa: F811 - the fixture's name
    msgs = [m for m in tab.headless.messages
            if m.type == "RegisterCommandMessage" and m.fields["props"]["label"] == label]
    return msgs[-1].fields["props"] if msgs else None


def test_viewer_label_set_service_serves_the_demo_sequence_paper(live_api):
    api = ApiClient(live_api.url, live_api.operator_token)
    table = ClassTable.from_service(api.label_set(live_api.sequence_id))
    assert table == PAPER and table.classes == SAMPLE_CLASSES and table.fallback == "unknown"


def test_viewer_label_set_classes_follow_the_shown_tracks_sequence(tab, viewer, live_api, monkeypatch):  # noqa: F811
    assert tab.review.table == PAPER
    ids = [t["id"] for t in ApiClient(live_api.url, live_api.admin_token).list_tracks(
        sequence_id=live_api.sequence_id, limit=3)["items"]]
    # the service serves the sequence's set as another one: the tab shows a track of it
    monkeypatch.setattr(tab.api, "label_set", lambda _sid: CAMPUS)
    viewer.label_sets = LabelSets()
    tab.open_track(ids[1])
    wait_until(lambda: tab.review.table.name == "campus")
    assert tab.review.buttons["Class 1-3"].options == ("Q walker", "cart", "dog")
    assert not any(k.startswith("Class 5") for k in tab.review.buttons)
    b = tab.review.buttons  # the new group sits where the old ones were: after Discard, before Truncate
    assert b["Discard (D)"].order < b["Class 1-3"].order < b["Truncate"].order
    wait_until(lambda: _command(tab, "Class walker") is not None)
    assert _command(tab, "Class walker")["hotkey"] == "Q" and _command(tab, "Class cart")["hotkey"] is None
    assert "**Q** class" in tab.review.gui_keys.content and "1-7" not in tab.review.gui_keys.content
    assert tab.bulk.gui_class.options == ("walker", "cart", "dog")
    assert tab.repair.gui_predicted_class.options == ("walker", "cart", "dog")
    assert tab.scene.table.colours["cart"].tolist() == [0, 0, 255]
    # a track of a paper sequence brings the paper classes back
    monkeypatch.undo()
    viewer.label_sets = LabelSets()
    tab.open_track(ids[2])
    wait_until(lambda: tab.review.table == PAPER)
    labels = [*tab.review.buttons["Class 1-4"].options, *tab.review.buttons["Class 5-7"].options]
    assert labels == [f"{i + 1} {name}" for i, name in enumerate(SAMPLE_CLASSES)]
    assert "**1-7** class" in tab.review.gui_keys.content
    assert tab.bulk.gui_class.options == SAMPLE_CLASSES
