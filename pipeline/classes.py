"""The class table: our classes and the one mapping to and from SemanticKITTI ids.

Our sample classes (index = CNN output index)::

    0 person   1 car   2 cyclist   3 trunk   4 bush   5 building   6 unknown

`GROUND` (7) is a point class only, never a sample class, and `UNLABELLED` (255) marks
points that carry no class (unlabelled or outlier in SemanticKITTI, or unsegmented).
Remapping goes through numpy lookup tables over the 16-bit semantic id.
"""

from __future__ import annotations

import numpy as np

SAMPLE_CLASSES: tuple[str, ...] = ("person", "car", "cyclist", "trunk", "bush", "building", "unknown")
NUM_SAMPLE_CLASSES = len(SAMPLE_CLASSES)  # K = 7
GROUND = NUM_SAMPLE_CLASSES  # 7: the point class after the sample classes
UNLABELLED = 255
POINT_CLASSES: tuple[str, ...] = (*SAMPLE_CLASSES, "ground")
CLASS_INDEX: dict[str, int] = {name: i for i, name in enumerate(POINT_CLASSES)}

# SemanticKITTI ids of each of our classes. "unknown" takes every other id that is not
# unlabelled (0) or outlier (1); see `to_ours`.
SEMANTICKITTI_IDS: dict[str, tuple[int, ...]] = {
    "person": (30, 254),
    "car": (10, 13, 18, 20, 252, 256, 257, 258, 259),
    "cyclist": (31, 32, 253, 255),
    "trunk": (71,),
    "bush": (70,),
    "building": (50,),
    "ground": (40, 44, 48, 49, 60, 72),
}
SEMANTICKITTI_UNLABELLED_IDS: tuple[int, ...] = (0, 1)

# Representative SemanticKITTI id written for each of our classes (static variant).
SEMANTICKITTI_WRITE_ID: dict[str, int] = {
    "person": 30,
    "car": 10,
    "cyclist": 31,
    "trunk": 71,
    "bush": 70,
    "building": 50,
    "unknown": 80,  # pole: any id outside the table maps back to unknown
    "ground": 40,
}
MOVING_IDS: dict[str, int] = {"car": 252, "cyclist": 253, "person": 254}

# Colours (RGB uint8) used by viewers and plots, per point class.
CLASS_COLOURS: dict[str, tuple[int, int, int]] = {
    "person": (255, 30, 30),
    "car": (100, 150, 245),
    "cyclist": (255, 200, 20),
    "trunk": (135, 60, 0),
    "bush": (0, 175, 0),
    "building": (200, 200, 200),
    "unknown": (150, 0, 255),
    "ground": (80, 80, 80),
}


def _build_to_ours() -> np.ndarray:
    lut = np.full(1 << 16, CLASS_INDEX["unknown"], dtype=np.uint8)
    for sk in SEMANTICKITTI_UNLABELLED_IDS:
        lut[sk] = UNLABELLED
    for name, ids in SEMANTICKITTI_IDS.items():
        lut[list(ids)] = CLASS_INDEX[name]
    return lut


_TO_OURS = _build_to_ours()
_TO_SEMANTICKITTI = np.zeros(256, dtype=np.uint16)
for _name, _sk in SEMANTICKITTI_WRITE_ID.items():
    _TO_SEMANTICKITTI[CLASS_INDEX[_name]] = _sk
_TO_SEMANTICKITTI[UNLABELLED] = 0


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
    table = np.full((256, 3), 40, dtype=np.uint8)
    for name, rgb in CLASS_COLOURS.items():
        table[CLASS_INDEX[name]] = rgb
    return table
