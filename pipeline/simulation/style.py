"""Campus styles: the distributions objects are drawn from.

A new scene in the paper (its test part D) is another part of the campus: another layout, but
also other cars, other trees, other people. Style "a" is the default campus; style "b" draws
from shifted distributions (more vans and SUVs and more dark paint, more children and darker
clothes, more columnar and spreading shrubs, more conifers and wide crowns, more glass), so a
model trained on style "a" meets a domain shift there, as a pretrained model meets a new scene.
Every style makes the same random draws in the same order, so style "a" reproduces the default
campus byte for byte.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.simulation import models as m


@dataclass(frozen=True)
class CampusStyle:
    """Defaults: the simulator's own draws (style a)."""

    name: str
    car_kind_p: tuple[float, ...] = m.CAR_KIND_P  # small, sedan, suv, van
    dark_share: float = m.DARK_SHARE  # cars with dark paint
    child_share: float = m.CHILD_SHARE
    cloth_refl: tuple[float, float] = m.CLOTH_REFL  # remission range of clothes
    carry_p: tuple[float, ...] = m.CARRY_P  # nothing, bag, umbrella, coat
    bush_p: tuple[float, ...] = m.BUSH_P  # round, columnar, spreading, sparse
    tree_styles: tuple[str, ...] = ("young", "mature", "mature", "conifer", "wide")  # drawn uniformly
    row_tree_styles: tuple[str, ...] = ("young", "mature", "wide")  # avenue rows
    glass_share: float = 0.25  # buildings with glass fronts

    def draw_car(self, rng: np.random.Generator, kind: str | None = None) -> m.CarShape:
        return m.draw_car(rng, self.dark_share, kind=kind, kind_p=self.car_kind_p)

    def draw_person(self, rng: np.random.Generator) -> m.PersonShape:
        return m.draw_person(rng, self.child_share, self.cloth_refl, self.carry_p)


STYLES: dict[str, CampusStyle] = {
    "a": CampusStyle("a"),
    "b": CampusStyle(
        "b",
        car_kind_p=(0.1, 0.25, 0.35, 0.3),
        dark_share=0.5,
        child_share=0.25,
        cloth_refl=(0.04, 0.35),
        carry_p=(0.4, 0.25, 0.15, 0.2),
        bush_p=(0.25, 0.3, 0.25, 0.2),
        tree_styles=("conifer", "conifer", "wide", "wide", "young"),
        row_tree_styles=("conifer", "wide", "young"),
        glass_share=0.55,
    ),
}


def get_style(name: str) -> CampusStyle:
    """The style called `name` (ValueError naming the valid ones otherwise)."""
    try:
        return STYLES[name]
    except KeyError:
        raise ValueError(f"unknown campus style {name!r}; valid: {', '.join(STYLES)}") from None
