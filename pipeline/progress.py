"""Progress on the terminal: a `Progress` object passed down instead of a boolean flag.

`QUIET` (the default everywhere) reports nothing; `TqdmProgress()` draws one tqdm bar on stderr
per stage, which is what the CLI passes. Library code asks for a bar and updates it without
knowing which one it got:

    with progress.bar(len(frames), "process") as bar:
        for frame in frames:
            ...
            bar.update()
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from typing import Any, TypeVar

T = TypeVar("T")


class Bar:
    """A bar that shows nothing (the quiet one); TqdmProgress's bars are tqdm's."""

    def update(self, n: int = 1) -> None:
        pass

    def set_postfix(self, **values: Any) -> None:
        pass

    def close(self) -> None:
        pass

    def __enter__(self) -> Bar:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class Progress:
    """Reports nothing: the null object (`QUIET`)."""

    def bar(self, total: int | None, desc: str, unit: str = "frame", **options: Any) -> Bar:
        """A bar of `total` steps named `desc`; `options` go to tqdm (position, leave)."""
        return Bar()

    def iterate(self, items: Iterable[T], desc: str, unit: str = "frame", total: int | None = None) -> Iterator[T]:
        """`items`, advancing a bar per item."""
        if total is None and hasattr(items, "__len__"):
            total = len(items)  # type: ignore[arg-type]
        with self.bar(total, desc, unit) as bar:
            for item in items:
                yield item
                bar.update()


class TqdmProgress(Progress):
    """A tqdm bar on stderr per stage."""

    def bar(self, total: int | None, desc: str, unit: str = "frame", **options: Any) -> Bar:
        from tqdm import tqdm

        return tqdm(total=total, desc=desc, unit=unit, **options)  # type: ignore[return-value]


QUIET = Progress()
