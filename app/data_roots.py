"""What the service may read: files whose real path lies under the configured data roots.

- **Links, any number of hops.** Every path is resolved to its real path (`Path.resolve`
  follows each symlink, however many there are), and a tree is walked following the links to
  folders (each real folder once, so a loop ends), checking the real path of every entry: a
  link inside the roots to a folder whose file links outside is refused like a direct one.
- **Hard links.** A hard link has no "real path" to resolve: both names are the same file. A
  regular file with more links (`st_nlink`) than the walk finds under the roots has a name
  elsewhere, and is refused; the walk reads the whole roots only when a file of the sequence
  has links it did not find in the sequence's own folder.
- **Every read.** `GuardedSource` checks each frame's files again just before the reader opens
  them (a link swapped in after registration is caught at ingest): real path under the roots,
  and a file with several links only when the ingest's tree check counted all of them.

Refusals are `Forbidden` (403 in the API, a failed job in a worker) naming the entry relative to
the folder that was checked, never the outside target.
"""

from __future__ import annotations

import os
import stat
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from app.core.errors import Forbidden


@dataclass
class DataRoots:
    """The real paths of the data roots and the hard-linked files found to be all inside them."""

    roots: list[Path]
    linked_ok: set[tuple[int, int]] = field(default_factory=set)  # (st_dev, st_ino) of multi-link files

    @classmethod
    def of(cls, roots: list[Path]) -> DataRoots:
        return cls([Path(r).resolve() for r in roots])

    def contains(self, real: Path) -> bool:
        return any(real == r or real.is_relative_to(r) for r in self.roots)

    def real_inside(self, path: Path, shown: str) -> Path:
        """`path`'s real path; Forbidden when it lies outside the roots (`shown` names it)."""
        try:
            real = path.resolve()
        except (OSError, RuntimeError) as exc:  # a link loop, a name too long
            raise Forbidden(f"{shown} cannot be resolved ({type(exc).__name__}); refused") from None
        if not self.contains(real):
            raise Forbidden(f"{shown} resolves outside the configured data roots; refused")
        return real

    def check_tree(self, path: Path) -> None:
        """Every entry under `path` (and `path`) is inside the roots, whatever the hops; files
        with hard links elsewhere are refused. Remembers the hard-linked files it cleared."""
        real = self.real_inside(path, path.name)
        multi: dict[tuple[int, int], tuple[str, int]] = {}
        seen: Counter[tuple[int, int]] = Counter()
        for shown, st in self._walk(path, real):
            if stat.S_ISREG(st.st_mode) and st.st_nlink > 1:
                key = (st.st_dev, st.st_ino)
                multi.setdefault(key, (shown, st.st_nlink))
                seen[key] += 1
        unexplained = {k: v for k, v in multi.items() if seen[k] < v[1]}
        if unexplained:
            self._count_in_roots(unexplained, seen)
        for key, (shown, nlink) in multi.items():
            if seen[key] < nlink:
                raise Forbidden(f"{shown} is a hard link to a file with a name outside the configured data roots; refused")
            self.linked_ok.add(key)

    def _walk(self, top: Path, real_top: Path) -> Iterator[tuple[str, os.stat_result]]:
        """(name relative to `top`, stat of the real file) of every entry, following links
        to folders once per real folder; each entry's real path is checked on the way."""
        if not real_top.is_dir():
            yield top.name, real_top.stat()
            return
        visited = {real_top}
        for folder, dirs, files in os.walk(top, followlinks=True):
            for name in sorted((*dirs, *files)):
                entry = Path(folder) / name
                shown = entry.relative_to(top).as_posix()
                real = self.real_inside(entry, shown)
                try:
                    st = real.stat()
                except OSError:
                    continue  # a dangling link inside the roots reads nothing
                yield shown, st
            kept = []
            for name in dirs:  # descend each real folder once (a link loop ends)
                real = (Path(folder) / name).resolve()
                if real not in visited:
                    visited.add(real)
                    kept.append(name)
            dirs[:] = kept

    def _count_in_roots(self, wanted: dict[tuple[int, int], Any], seen: Counter[tuple[int, int]]) -> None:
        """Count the names of the `wanted` files anywhere under the roots (links not followed:
        each name is counted once), replacing the sequence-only counts."""
        for key in wanted:
            seen[key] = 0
        for root in self.roots:
            for folder, _dirs, files in os.walk(root):
                for name in files:
                    try:
                        st = os.lstat(os.path.join(folder, name))
                    except OSError:
                        continue
                    key = (st.st_dev, st.st_ino)
                    if key in wanted:
                        seen[key] += 1

    def check_file(self, path: Path, shown: str) -> None:
        """One file about to be read: real path inside, and no hard link the tree check did not clear."""
        real = self.real_inside(path, shown)
        try:
            st = real.stat()
        except OSError:
            return  # missing: the reader reports it as the corrupt frame it is
        if stat.S_ISREG(st.st_mode) and st.st_nlink > 1 and (st.st_dev, st.st_ino) not in self.linked_ok:
            raise Forbidden(f"{shown} is a hard link that the sequence's check did not clear; refused")


def sensor_file(name: str) -> Path | None:
    """The file a pipeline config's `sensor.name` reads (an Ouster metadata json), None for a
    preset or `auto`."""
    from pipeline.sensors import PRESETS

    return None if name in ("auto", *PRESETS) else Path(name)


class GuardedSource:
    """A `pipeline.scan.SequenceSource` whose frames are checked (`DataRoots.check_file`) just
    before the reader opens them. Which files a frame reads: the reader's per-frame list
    (`_files[i]`, and the label file when it has one), else its one recording file (`path`)."""

    def __init__(self, source: Any, roots: DataRoots) -> None:
        self._source = source
        self._roots = roots

    def __getattr__(self, name: str) -> Any:
        return getattr(self._source, name)

    def __len__(self) -> int:
        return len(self._source)

    def frame_files(self, index: int) -> list[Path]:
        files = getattr(self._source, "_files", None)
        out = [Path(files[index])] if files is not None else [Path(self._source.path)]
        label_path = getattr(self._source, "label_path", None)
        label = label_path(index) if callable(label_path) else None
        return out + ([Path(label)] if label is not None else [])

    def frame(self, index: int) -> Any:
        for f in self.frame_files(index):
            self._roots.check_file(f, f.name)
        return self._source.frame(index)
