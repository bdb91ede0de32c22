"""Which label set a sequence and a model speak: checked when a sequence is registered and when a
job that runs a model on a sequence is queued."""

from __future__ import annotations

from app.core.errors import Invalid


def check_service_label_set(name: str) -> None:
    """Invalid (422) unless `name` is a preset whose classes the service speaks: review, training
    and the exports use the default set's classes, so a sequence of another set would be labelled
    in classes it does not have."""
    from pipeline.errors import ConfigError
    from pipeline.label_sets import DEFAULT_LABEL_SET, preset

    try:
        label_set = preset(name)
    except ConfigError as exc:
        raise Invalid(f"label_set: {exc}") from None
    if not label_set.same_classes(preset(DEFAULT_LABEL_SET)):
        raise Invalid(f"label_set: {name!r} is not supported by the service yet: review, training and "
                      f"the exports speak the classes of {DEFAULT_LABEL_SET!r} only")


def require_model_label_set(name: str, path: str, label_set: str) -> None:
    """Invalid (422) when the checkpoint at `path` was trained on another label set than
    `label_set` (a preset name). A checkpoint that cannot be read is left to the job, which
    reports it as its failure."""
    from pipeline.errors import DataError, LabelSetMismatch
    from pipeline.label_sets import load_label_set
    from pipeline.model import check_label_set, load_checkpoint

    try:
        _, meta = load_checkpoint(path, "cpu")
    except DataError:
        return
    try:
        check_label_set(meta, load_label_set(label_set), path)
    except LabelSetMismatch as exc:
        raise Invalid(f"{name}: {exc}") from None
