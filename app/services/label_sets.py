"""Which label set a model speaks: jobs that run a model on a sequence check it when queued."""

from __future__ import annotations

from app.core.errors import Invalid


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
