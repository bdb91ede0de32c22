"""Which label set a sequence and a model speak: given when a sequence is registered (a preset's
name, or a label set as data), and checked when a job that runs a model on a sequence is queued."""

from __future__ import annotations

from typing import Any

from app.core.errors import Invalid
from pipeline.label_sets import LabelSet


def registration_label_set(value: str | dict[str, Any]) -> tuple[LabelSet, dict[str, Any] | None]:
    """The label set a sequence is registered with, and the definition to store with it (None for
    a preset, which is stored by name). Invalid (422) naming the field for an unknown preset, a
    label set that is not valid, or a label set given as data under a preset's name (which would
    make the name mean two sets)."""
    from pipeline.errors import ConfigError
    from pipeline.label_sets import preset, preset_names, validate_label_set

    try:
        if isinstance(value, str):
            return preset(value), None
        label_set = validate_label_set(value, "label_set")
    except ConfigError as exc:
        raise Invalid(str(exc) if str(exc).startswith("label_set") else f"label_set: {exc}") from None
    if label_set.name in preset_names():
        raise Invalid(f"label_set: field name: {label_set.name!r} is a preset's name; give the preset by its "
                      "name, or name your label set otherwise")
    return label_set, label_set.model_dump(mode="json")


def require_model_label_set(name: str, path: str, label_set: LabelSet) -> None:
    """Invalid (422) when the checkpoint at `path` was trained on another label set than
    `label_set` (the sequence's). A checkpoint that cannot be read is left to the job, which
    reports it as its failure."""
    from pipeline.errors import DataError
    from pipeline.model import load_checkpoint

    try:
        _, meta = load_checkpoint(path, "cpu")
    except DataError:
        return
    check_model_label_set(name, meta, path, label_set)


def check_model_label_set(name: str, meta: Any, path: str, label_set: LabelSet) -> None:
    """`require_model_label_set` for a checkpoint already loaded (`meta`: its CheckpointMeta)."""
    from pipeline.errors import LabelSetMismatch
    from pipeline.model import check_label_set

    try:
        check_label_set(meta, label_set, path)
    except LabelSetMismatch as exc:
        raise Invalid(f"{name}: {exc}") from None
