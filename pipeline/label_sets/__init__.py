"""Label sets as data: the classes of a project in a YAML file, validated, with shipped presets.

`paper` (the method's seven classes plus ground) is the default and is what `pipeline.classes`
exposes; `semantickitti` and `nuscenes` follow those datasets' evaluation classes. A custom file
is given by path; `from_semantickitti_yaml` imports a semantic-kitti.yaml style file.
"""

from __future__ import annotations

from pipeline.label_sets.load import (
    DEFAULT_LABEL_SET,
    dump_label_set,
    load_label_set,
    preset,
    preset_names,
    read_label_set,
    validate_label_set,
)
from pipeline.label_sets.model import UNLABELLED, LabelClass, LabelSet
from pipeline.label_sets.semantickitti_yaml import from_semantickitti_yaml

__all__ = [
    "DEFAULT_LABEL_SET",
    "UNLABELLED",
    "LabelClass",
    "LabelSet",
    "dump_label_set",
    "from_semantickitti_yaml",
    "load_label_set",
    "preset",
    "preset_names",
    "read_label_set",
    "validate_label_set",
]
