"""Every key and review button of a tab, in one table: adding an action is one row here; the
class rows come from the label set of the shown track's sequence (`actions_for(table)`).

A row with `review` set is a review action on the shown track (`ClientTab.run_action`: the key is
bound to the track that was on screen when it arrived); one with `call` is a view command (frame
steps, play, the repair panel's splits). A row with `button` also gets a button in the Review
tab; rows sharing a `group` become one button group, in table order.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from annotator_ui.label_set import PAPER, ClassTable


@dataclass(frozen=True)
class Action:
    label: str  # the command palette's name
    key: str | None  # viser hotkey (None: a button only)
    short: str  # the key help's words
    help: str  # the command palette's description
    review: str | None = None  # a ReviewSession method (accept, truncate_before, undo, skip, ...) or a service action
    arg: str | None = None  # the class of a label action
    call: Callable[[Any], Any] | None = None  # tab -> None, for view commands
    button: str | None = None  # text of its button in the Review tab (None: key only)
    group: str | None = None  # button group label
    colour: str | None = None
    icon: str | None = None


def _class_group(i: int, n: int) -> str:
    """The button group of class button i of n: four a row ('Class 1-4', 'Class 5-7')."""
    first = i // 4 * 4
    return f"Class {first + 1}-{min(first + 4, n)}"


BEFORE_CLASSES: tuple[Action, ...] = (
    Action("Accept track", "A", "accept", "accept the track as it is and load the next one", review="accept",
           button="Accept (A)", colour="green", icon="CHECK"),
    Action("Discard track", "D", "discard", "discard the track (a wrong association) and load the next one",
           review="discard", button="Discard (D)", colour="red", icon="TRASH"),
)
AFTER_CLASSES: tuple[Action, ...] = (
    Action("Truncate before frame", "[", "truncate before / after", "keep the current frame and the ones after it",
           review="truncate_before", button="[ before frame", group="Truncate"),
    Action("Truncate after frame", "]", "truncate before / after", "keep the current frame and the ones before it",
           review="truncate_after", button="after frame ]", group="Truncate"),
    Action("Undo", "Z", "undo", "revert this tab's last action and show that track", review="undo",
           button="Undo (Z)", icon="ARROW_BACK_UP"),
    Action("Skip track", "S", "skip", "pass this track over and load the next one", review="skip",
           button="Skip (S)", icon="PLAYER_SKIP_FORWARD"),
    Action("Previous frame", "arrowleft", "frame", "step one frame back", call=lambda tab: tab.playback.step(-1)),
    Action("Next frame", "arrowright", "frame", "step one frame forward", call=lambda tab: tab.playback.step(+1)),
    Action("Play / pause", "space", "play", "play the track's frames", call=lambda tab: tab.playback.toggle()),
    Action("Split by height", "H", "split by height / predicted class", "cut the track's points above the set height into a new track",
           call=lambda tab: tab.repair.cut_height()),
    Action("Split by predicted class", "P", "split by height / predicted class",
           "cut the segments the newest model calls the chosen class into a new track",
           call=lambda tab: tab.repair.cut_predicted()),
)

OWN_KEYS = frozenset(a.key for a in (*BEFORE_CLASSES, *AFTER_CLASSES) if a.key is not None)


def class_actions(table: ClassTable) -> tuple[Action, ...]:
    """One row per class of `table`: its hotkey (none when the tab's own actions use it) and its
    button, '<key> <name>' (or the name alone), four to a group."""
    rows = []
    for i, name in enumerate(table.classes):
        key = table.key(name, OWN_KEYS)
        rows.append(Action(f"Class {name}", key, "class", f"label the track '{name}' (accepts it) and load the next one",
                           review="label", arg=name, button=name if key is None else f"{key} {name}",
                           group=_class_group(i, len(table.classes))))
    return tuple(rows)


def actions_for(table: ClassTable) -> tuple[Action, ...]:
    """Every row of a tab that shows the classes of `table`, in table order."""
    return (*BEFORE_CLASSES, *class_actions(table), *AFTER_CLASSES)


ACTIONS: tuple[Action, ...] = actions_for(PAPER)  # before a tab knows its sequence: the default set's

_KEY_NAMES = {"arrowleft": "←", "arrowright": "→"}


def key_help(actions: tuple[Action, ...] = ACTIONS) -> str:
    """'**A** accept · **D** discard · **1-7** class · ...': consecutive rows of one `short` share it."""
    runs: list[tuple[list[str], str]] = []
    for a in actions:
        if a.key is None:
            continue
        key = _KEY_NAMES.get(a.key, a.key)
        if runs and runs[-1][1] == a.short:
            runs[-1][0].append(key)
        else:
            runs.append(([key], a.short))
    parts = []
    for keys, short in runs:
        both = f"**{keys[0]}-{keys[-1]}**" if len(keys) > 2 else " / ".join(f"**{k}**" for k in keys)
        parts.append(f"{both} {short}")
    return " · ".join(parts) + " · click a point: open its track"


def review_action(label: str, actions: tuple[Action, ...] = ACTIONS) -> Action:
    """The review row of a button's text."""
    return next(a for a in actions if a.button == label)
