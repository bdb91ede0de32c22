"""Campus styles: the distributions objects are drawn from.

A new scene in the paper (its test part D) is another part of the campus: another layout, but
also other cars, other trees, other people. Style "a" is the default campus; style "b" draws
from shifted distributions (more vans and SUVs and more dark paint, more children and darker
clothes, more columnar and spreading shrubs, more conifers and wide crowns, more glass), so a
model trained on style "a" meets a domain shift there, as a pretrained model meets a new scene.
Every style makes the same random draws in the same order, so style "a" reproduces the default
campus byte for byte.

The varied styles "a+" and "b+" are "a" and "b" with a longer tail of object kinds in every class
(`variety`): hatchbacks, pickups and box vans, some with roof boxes; pruned box shrubs and
standards (a ball of leaves on a stem); people walking in groups and
people sitting on benches; child cyclists, cargo bikes and e-scooter riders; leaning and forked
trunks, some in metal tree guards; hydrants, post boxes, utility cabinets, planters and statues;
kiosks and sheds (small buildings). A few labels per class then miss whole kinds, as they do on a
real campus. Their extra draws come from separate random streams, so "a+" has the route,
traffic, people and trees of "a" plus the extra kinds (cars and cyclists switch kind in place;
a longer parked car may no longer fit its bay, which shifts the later placements a little).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from research.simulation import models as m


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
    # --- the varied styles (`variety`): kinds the plain styles never draw
    variety: bool = False
    extra_car_p: tuple[float, ...] = (0.14, 0.1, 0.08)  # a car is instead a hatchback, pickup, box van
    roof_box_share: float = 0.12
    group_share: float = 0.3  # walkers with one or two companions (one object: they walk as one)
    sitting_share: float = 0.6  # benches with someone sitting on them
    cyclist_kind_p: tuple[float, ...] = (0.55, 0.15, 0.12, 0.18)  # bike, child, cargo, scooter
    lean_share: float = 0.35  # trees leaning 4-14 degrees
    fork_share: float = 0.2  # trees with a second stem
    guard_share: float = 0.2  # young and mature trees in a metal tree guard
    extra_furniture: float = 2.0  # factor on hydrants, post boxes, cabinets, planters, statues, kiosks
    varied_bush_share: float = 0.3  # bushes that are instead pruned boxes or standards (a ball on a stem)

    def draw_car(
        self, rng: np.random.Generator, kind: str | None = None, extra: np.random.Generator | None = None
    ) -> m.CarShape:
        """A car of this style. In the varied styles, `extra` (a separate stream) may then replace it
        by a hatchback, pickup or box van (`extra_car_p`) and give it a roof box."""
        car = m.draw_car(rng, self.dark_share, kind=kind, kind_p=self.car_kind_p)
        if kind is not None:
            return car
        return self.vary_car(car, extra)

    def vary_car(self, car: m.CarShape, extra: np.random.Generator | None) -> m.CarShape:
        """`car` itself, or in the varied styles maybe (drawn from the separate stream `extra`) a
        hatchback, pickup or box van instead, maybe with a roof box."""
        if not self.variety or extra is None:
            return car
        u = extra.random()
        cum = np.cumsum(self.extra_car_p)
        if u < cum[-1]:
            car = m.draw_car(extra, self.dark_share, kind=m.EXTRA_CAR_KINDS[int(np.searchsorted(cum, u, "right"))])
        roof = bool(extra.random() < self.roof_box_share) and car.kind not in ("boxvan", "pickup")
        return replace(car, roof_box=roof)

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
STYLES["a+"] = replace(STYLES["a"], name="a+", variety=True)
STYLES["b+"] = replace(
    STYLES["b"], name="b+", variety=True, extra_car_p=(0.06, 0.16, 0.14), roof_box_share=0.2,
    cyclist_kind_p=(0.45, 0.2, 0.15, 0.2), group_share=0.4,
)


def get_style(name: str) -> CampusStyle:
    """The style called `name` (ValueError naming the valid ones otherwise)."""
    try:
        return STYLES[name]
    except KeyError:
        raise ValueError(f"unknown campus style {name!r}; valid: {', '.join(STYLES)}") from None
