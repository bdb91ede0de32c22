"""The classes a tab shows: the label set of the sequence of the shown track, as the service
serves it (`GET /sequences/{id}/label-set`, read through `ApiClient.label_set`). Its class
buttons, hotkeys, colours and dropdowns come from here; a track of another sequence brings its
own set. `PAPER` (the default label set, from pipeline.label_sets) is what a tab shows before
the first track arrives."""

from __future__ import annotations

import threading
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from annotator_ui.client import ApiClient

# keys viser binds without a modifier (viser._messages.HotkeyKey): a class key outside them, or one
# the tab's own actions use, gets a button but no hotkey
_BINDABLE = frozenset([*(chr(c) for c in range(ord("A"), ord("Z") + 1)), *"0123456789"])


@dataclass(frozen=True)
class ClassTable:
    """A label set's classes that a track can take (not ground), in index order: `colours` RGB
    uint8 (3,) and `keys` the hotkey per class (None: none)."""

    name: str
    classes: tuple[str, ...]
    colours: Mapping[str, np.ndarray] = field(compare=False)
    keys: Mapping[str, str | None] = field(compare=False)
    fallback: str | None = None  # the class of what no other class fits, when the set has one

    @classmethod
    def from_service(cls, data: Mapping[str, Any]) -> ClassTable:
        """From the service's LabelSetPublic JSON."""
        rows = [c for c in data["classes"] if not c["ground"]]
        return cls(
            name=str(data["name"]),
            classes=tuple(str(c["name"]) for c in rows),
            colours={str(c["name"]): np.array(c["colour"], np.uint8) for c in rows},
            keys={str(c["name"]): _bindable(c.get("key")) for c in rows},
            fallback=data.get("fallback"),
        )

    def set_dropdown(self, dropdown: Any) -> None:
        """Give a class dropdown these classes, keeping its choice when it is one of them."""
        value = dropdown.value
        dropdown.options = self.classes
        dropdown.value = value if value in self.classes else self.classes[0]

    def key(self, name: str, taken: frozenset[str] = frozenset()) -> str | None:
        """The class's hotkey, None when it has none or `taken` (the tab's own keys) holds it."""
        key = self.keys.get(name)
        return None if key is None or key in taken else key


def _bindable(key: str | None) -> str | None:
    if key is None:
        return None
    key = key.upper()
    return key if key in _BINDABLE else None


def _paper() -> ClassTable:
    from pipeline.label_sets import DEFAULT_LABEL_SET, preset

    s = preset(DEFAULT_LABEL_SET)
    data = {"name": s.name, "classes": [c.model_dump() for c in s.point_classes], "fallback": s.fallback}
    return ClassTable.from_service(data)


PAPER = _paper()


class LabelSets:
    """The class table of each sequence, read once from the service (the viewer's tabs share it)."""

    def __init__(self) -> None:
        self._tables: dict[int, ClassTable] = {}
        self._lock = threading.Lock()

    def of(self, api: ApiClient, sequence_id: int) -> ClassTable:
        with self._lock:
            table = self._tables.get(sequence_id)
        if table is None:
            table = ClassTable.from_service(api.label_set(sequence_id))
            with self._lock:
                self._tables[sequence_id] = table
        return table
