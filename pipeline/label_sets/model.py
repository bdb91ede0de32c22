"""A label set: the classes of one labelling project, their colours, keys and SemanticKITTI ids.

Index order (`LabelSet.point_classes`): the classes that are not ground first, in file order
(their index is the CNN output index), then the ground classes. `UNLABELLED` (255) marks points
that carry no class, so a label set holds at most 255 classes. SemanticKITTI ids are the low 16
bits of a `.label` entry; remapping goes through numpy lookup tables.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable
from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

UNLABELLED = 255  # the class index of a point without class
UNLABELLED_COLOUR = (40, 40, 40)

Channel = Annotated[int, Field(ge=0, le=255)]
SemanticId = Annotated[int, Field(ge=0, le=0xFFFF)]
Name = Annotated[str, Field(min_length=1, max_length=64, pattern=r"^[a-z0-9][a-z0-9_-]*$")]


class LabelClass(BaseModel):
    """One class: what the viewer shows and which SemanticKITTI ids it reads and writes."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: Name
    colour: tuple[Channel, Channel, Channel]  # RGB
    key: str | None = Field(default=None, min_length=1, max_length=16, pattern=r"^\S+$")  # None: no hotkey
    reads: tuple[SemanticId, ...] = ()  # SemanticKITTI ids read as this class
    writes: SemanticId  # the id written for it (static variant)
    moving: SemanticId | None = None  # the id written for its moving variant
    kind: Literal["thing", "stuff"]
    ground: bool = False

    @model_validator(mode="after")
    def _moving_is_read(self) -> LabelClass:
        if self.moving is not None and self.moving not in self.reads:
            raise ValueError(f"moving: {self.name}'s moving id {self.moving} is not among the ids it reads")
        return self


def _repeated(values: Iterable[object]) -> list[object]:
    return [v for v, n in Counter(values).items() if n > 1]


class LabelSet(BaseModel):
    """The classes of a project, validated: unique names, keys and ids, at least one class."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: Name
    description: str = ""
    classes: tuple[LabelClass, ...] = Field(min_length=1, max_length=UNLABELLED)
    unlabelled_ids: tuple[SemanticId, ...] = (0,)  # SemanticKITTI ids read as no class
    fallback: Name | None = None  # the class of every id that no class reads (None: unlabelled)

    @field_validator("classes")
    @classmethod
    def _unique(cls, classes: tuple[LabelClass, ...]) -> tuple[LabelClass, ...]:
        for field, values in (
            ("name", [c.name for c in classes]),
            ("key", [c.key for c in classes if c.key is not None]),
            ("writes", [i for c in classes for i in (c.writes, c.moving) if i is not None]),
            ("reads", [i for c in classes for i in c.reads]),
        ):
            if dup := _repeated(values):
                raise ValueError(f"{field} {dup[0]!r} is given to more than one class")
        return classes

    @model_validator(mode="after")
    def _consistent(self) -> LabelSet:
        names = [c.name for c in self.classes]
        if self.fallback is not None and self.fallback not in names:
            raise ValueError(f"fallback: {self.fallback!r} is not a class; classes: {', '.join(names)}")
        read = {i for c in self.classes for i in c.reads}
        if both := read & set(self.unlabelled_ids):
            raise ValueError(f"unlabelled_ids: id {min(both)} is also read by a class")
        for c in self.classes:
            if c.writes not in c.reads and not (c.name == self.fallback and c.writes not in read):
                raise ValueError(f"classes: {c.name} writes {c.writes} but does not read it back")
        return self

    def same_classes(self, other: LabelSet) -> bool:
        """Whether both sets give every SemanticKITTI id and class index the same meaning."""
        return (self.classes, self.unlabelled_ids, self.fallback) == (other.classes, other.unlabelled_ids, other.fallback)

    # Order and lookups --------------------------------------------------------------------

    @property
    def sample_classes(self) -> tuple[LabelClass, ...]:
        """The classes that are not ground, in file order: the CNN's outputs."""
        return tuple(c for c in self.classes if not c.ground)

    @property
    def ground_classes(self) -> tuple[LabelClass, ...]:
        return tuple(c for c in self.classes if c.ground)

    @property
    def point_classes(self) -> tuple[LabelClass, ...]:
        """Every class in index order: sample classes, then ground classes."""
        return (*self.sample_classes, *self.ground_classes)

    @property
    def point_class_names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.point_classes)

    @property
    def sample_class_names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.sample_classes)

    @property
    def ground_index(self) -> int | None:
        """The class index of ground points, until ground is labelled by region: the set's first
        ground class (a set with several labels all ground as it); None when it has none."""
        ground = self.ground_classes
        return None if not ground else len(self.sample_classes)

    def index(self, name: str) -> int:
        """Index of a class by name; KeyError naming the valid classes."""
        names = self.point_class_names
        if name not in names:
            raise KeyError(f"unknown class {name!r} in label set {self.name}; valid: {', '.join(names)}")
        return names.index(name)

    # Lookup tables: built on each call (callers that remap often keep them) ---------------

    def to_index_table(self) -> np.ndarray:
        """(65536,) uint8: class index of each SemanticKITTI id (UNLABELLED where none)."""
        fallback = UNLABELLED if self.fallback is None else self.index(self.fallback)
        lut = np.full(1 << 16, fallback, dtype=np.uint8)
        lut[list(self.unlabelled_ids)] = UNLABELLED
        for i, c in enumerate(self.point_classes):
            lut[list(c.reads)] = i
        return lut

    def to_semantickitti_table(self) -> np.ndarray:
        """(256,) uint16: SemanticKITTI id written for each class index (UNLABELLED: 0)."""
        lut = np.zeros(UNLABELLED + 1, dtype=np.uint16)
        for i, c in enumerate(self.point_classes):
            lut[i] = c.writes
        return lut

    def colour_table(self) -> np.ndarray:
        """(256, 3) uint8 RGB per class index; unlabelled and unused indices dark grey."""
        table = np.tile(np.array(UNLABELLED_COLOUR, np.uint8), (UNLABELLED + 1, 1))
        for i, c in enumerate(self.point_classes):
            table[i] = c.colour
        return table
