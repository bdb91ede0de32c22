"""The label set of a sequence, read from its row: the preset it names, or the set given as data
at registration (`sequences.label_set_definition`). Review, bulk, anchors and audits check class
names against it; the jobs and exports take their classes from it."""

from __future__ import annotations

import json
from functools import lru_cache
from typing import Any

from sqlalchemy import bindparam, select
from sqlalchemy.orm import Session

from app.core.errors import Invalid
from app.models import Sequence
from pipeline.label_sets import DEFAULT_LABEL_SET, LabelSet, preset, validate_label_set

_SEQ = Sequence.__table__.c
# built once: every review action reads it, and building a statement costs more than running it
_SEQUENCE_LABEL_SET = select(_SEQ.label_set, _SEQ.label_set_definition).where(_SEQ.id == bindparam("sequence_id"))


def resolve_label_set(name: str, definition: dict[str, Any] | None) -> LabelSet:
    """A sequence's label set from its two columns: the stored definition, else the preset `name`."""
    if definition is None:
        return preset(name)
    return _from_definition(json.dumps(definition, sort_keys=True))


def label_set_of(sequence: Sequence) -> LabelSet:
    """The label set of a loaded sequence row."""
    return resolve_label_set(sequence.label_set, sequence.label_set_definition)


@lru_cache(maxsize=64)
def _from_definition(text: str) -> LabelSet:
    # validated at registration; validated again here, once per distinct definition
    return validate_label_set(json.loads(text), "label_set")


def sequence_label_set(session: Session, sequence_id: int | None) -> LabelSet | None:
    """The label set of a sequence; None for no id or an unknown one."""
    if sequence_id is None:
        return None
    row = session.connection().execute(_SEQUENCE_LABEL_SET, {"sequence_id": sequence_id}).first()
    return None if row is None else resolve_label_set(row[0], row[1])


def existing_label_set(session: Session, sequence_id: int) -> LabelSet:
    """The label set of a sequence that exists (a row that references it, by foreign key, or one
    a caller has checked)."""
    label_set = sequence_label_set(session, sequence_id)
    assert label_set is not None, sequence_id
    return label_set


def label_sets_in_use(session: Session) -> list[LabelSet]:
    """The distinct label sets of the registered sequences (JSON has no equality on PostgreSQL,
    so the rows are told apart here)."""
    seen: dict[str, LabelSet] = {}
    for name, definition in session.execute(select(_SEQ.label_set, _SEQ.label_set_definition)):
        key = json.dumps([name, definition], sort_keys=True)
        if key not in seen:
            seen[key] = resolve_label_set(name, definition)
    return list(seen.values())


def common_label_set(session: Session, sequence_ids: list[int], field: str = "sequence_ids") -> LabelSet:
    """The one label set of `sequence_ids` (a model is trained on one set's classes); Invalid
    naming `field` when they have several. Unknown ids are skipped (their callers check them);
    with none known, the default set."""
    sets: dict[int, LabelSet] = {}
    for sid in sequence_ids:
        label_set = sequence_label_set(session, sid)
        if label_set is not None:
            sets[sid] = label_set
    first = next(iter(sets.values()), None)
    if first is None:
        return preset(DEFAULT_LABEL_SET)
    for sid, label_set in sets.items():
        if not label_set.same_classes(first) or label_set.name != first.name:
            raise Invalid(f"{field}: sequence {sid} has label set {label_set.name!r}, sequence "
                          f"{next(iter(sets))} {first.name!r}: a model is trained on the classes of one label set")
    return first


def check_class(field: str, name: str | None, label_set: LabelSet, ground: bool = False) -> str:
    """`name` when it is one of the set's sample classes (those a track can take), or with
    `ground` any of its classes (a ground region's); Invalid (422) naming `field`, the set and
    its classes otherwise."""
    names = label_set.point_class_names if ground else label_set.sample_class_names
    if name not in names:
        raise Invalid(f"{field}: unknown class {name!r} in label set {label_set.name!r}; valid: {', '.join(names)}")
    return name


def check_class_filter(session: Session, field: str, name: str | None, sequence_id: int | None) -> None:
    """A list filter's class: one of the sequence's classes, or with no sequence one of any
    registered sequence's, the default set's when there is none (Invalid otherwise, so a misspelt
    class is not an empty page)."""
    if name is None:
        return
    one = sequence_label_set(session, sequence_id)
    sets = [one] if one is not None else (label_sets_in_use(session) or [preset(DEFAULT_LABEL_SET)])
    if not any(name in s.sample_class_names for s in sets):
        valid = sorted({c for s in sets for c in s.sample_class_names})
        raise Invalid(f"{field}: unknown class {name!r}; valid: {', '.join(valid)}")
