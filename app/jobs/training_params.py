"""The training options a job exposes, derived from `pipeline.config.TrainingConfig`.

The REST `train` and `finetune` jobs take these as flat parameters. Their types, bounds and
defaults are TrainingConfig's own (for `finetune`, those of `TrainingConfig.finetuning()`), so a
job trains with exactly the library's defaults unless a parameter says otherwise, and a new
default changes the job without being repeated here.
"""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, create_model
from pydantic.fields import FieldInfo

from pipeline.config import TrainingConfig

# The options an operator may set on a job; the rest (selection rule, closure, label draws, ...)
# stay at the library's defaults.
JOB_TRAINING_FIELDS: tuple[str, ...] = (
    "epochs",
    "steps_per_epoch",
    "batch_labelled",
    "pairs_per_label",
    "gamma",
    "lr",
    "lr_schedule",
    "balance_weight",
    "augment",
    "transitive_pairs",
    "seed",
    "threads",
)


def with_training_fields(name: str, base: type[BaseModel], defaults: TrainingConfig) -> type[BaseModel]:
    """`base` plus one field per JOB_TRAINING_FIELDS, typed and bounded as TrainingConfig's,
    defaulting to `defaults`' values."""
    fields: dict[str, Any] = {}
    for key in JOB_TRAINING_FIELDS:
        info = TrainingConfig.model_fields[key]
        fields[key] = (info.annotation, FieldInfo.merge_field_infos(info, default=getattr(defaults, key)))
    return create_model(name, __base__=base, __module__=base.__module__, **fields)


def job_training_config(params: BaseModel, defaults: TrainingConfig) -> TrainingConfig:
    """`defaults` with the job's training parameters applied (validated as TrainingConfig)."""
    return TrainingConfig.model_validate(
        defaults.model_dump() | {key: getattr(params, key) for key in JOB_TRAINING_FIELDS}
    )
