"""The default class table, read from the `paper` label set (pipeline/label_sets/paper.yaml).

Our sample classes (index = CNN output index)::

    0 person   1 car   2 cyclist   3 trunk   4 bush   5 building   6 unknown

`GROUND` (7) is a point class only, never a sample class, and `UNLABELLED` (255) marks points
that carry no class (unlabelled or outlier in SemanticKITTI, or unsegmented). Remapping goes
through the label set's numpy lookup tables over the 16-bit semantic id. Other label sets are
data (`pipeline.label_sets`); these names keep the callers that predate them unchanged.
"""

from __future__ import annotations

import numpy as np

from pipeline.label_sets import DEFAULT_LABEL_SET, preset
from pipeline.label_sets import UNLABELLED as UNLABELLED  # re-exported: many callers import it here

PAPER = preset(DEFAULT_LABEL_SET)

SAMPLE_CLASSES: tuple[str, ...] = PAPER.sample_class_names
NUM_SAMPLE_CLASSES = len(SAMPLE_CLASSES)
POINT_CLASSES: tuple[str, ...] = PAPER.point_class_names
CLASS_INDEX: dict[str, int] = {name: i for i, name in enumerate(POINT_CLASSES)}
# The paper set has one ground class, right after the sample classes.
GROUND = CLASS_INDEX[PAPER.ground_classes[0].name]

# SemanticKITTI ids read as each class; "unknown" (the set's fallback) takes every id no class
# reads that is not unlabelled (0) or outlier (1); see `to_ours`.
SEMANTICKITTI_IDS: dict[str, tuple[int, ...]] = {c.name: c.reads for c in PAPER.point_classes if c.reads}
SEMANTICKITTI_UNLABELLED_IDS: tuple[int, ...] = PAPER.unlabelled_ids
# Representative SemanticKITTI id written for each class (static variant, then moving).
SEMANTICKITTI_WRITE_ID: dict[str, int] = {c.name: c.writes for c in PAPER.point_classes}
MOVING_IDS: dict[str, int] = {c.name: c.moving for c in PAPER.point_classes if c.moving is not None}
# Colours (RGB uint8) used by viewers and plots, per point class.
CLASS_COLOURS: dict[str, tuple[int, int, int]] = {c.name: c.colour for c in PAPER.point_classes}


_TO_OURS = PAPER.to_index_table()
_TO_SEMANTICKITTI = PAPER.to_semantickitti_table()


def to_ours(semantic: np.ndarray) -> np.ndarray:
    """Map SemanticKITTI semantic ids (any int array, low 16 bits used) to our class indices (uint8)."""
    return _TO_OURS[np.asarray(semantic).astype(np.int64) & 0xFFFF]


def to_semantickitti(classes: np.ndarray) -> np.ndarray:
    """Map our class indices (0..7 or 255) to representative SemanticKITTI ids (uint16)."""
    return _TO_SEMANTICKITTI[np.asarray(classes).astype(np.int64) & 0xFF]


def class_index(name: str) -> int:
    """Index of a class by name; raises KeyError naming the valid classes."""
    try:
        return CLASS_INDEX[name]
    except KeyError:
        raise KeyError(f"unknown class {name!r}; valid: {', '.join(POINT_CLASSES)}") from None


def colour_table() -> np.ndarray:
    """(256, 3) uint8 colour per class index; unlabelled is dark grey."""
    return PAPER.colour_table()
