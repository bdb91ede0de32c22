"""`tracklabel demo`: simulate the campus scene, then make it ready to review as `tracklabel
label` does (database, users `admin` and `operator`, registration, ingest with a progress bar).

1. simulate OUT/sequence (skipped when it is already there);
2. `app.label.prepare` with OUT as the data folder;
3. return the URL and the tokens; the CLI then serves.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from app.core.config import Settings
from app.label import Source, prepare
from pipeline.progress import QUIET, Progress


@dataclass(frozen=True)
class DemoInfo:
    settings: Settings
    sequence_id: int
    url: str
    admin_token: str
    operator_token: str
    ingest_result: dict


def demo_settings(out: Path, port: int) -> Settings:
    out = out.resolve()
    return Settings(data_dir=out, data_roots=[out], port=port)


def prepare_demo(
    out: Path, frames: int, seed: int, port: int, log: Callable[[str], None] = print, progress: Progress = QUIET
) -> DemoInfo:
    from research.simulation import simulate_sequence

    settings = demo_settings(out, port)
    seq_dir = settings.data_dir / "sequence"
    if not (seq_dir / "velodyne").is_dir():
        log(f"simulating {frames} frames (seed {seed}) into {seq_dir}")
        log(simulate_sequence(seq_dir, frames=frames, seed=seed, progress=progress).describe())
    else:
        log(f"using the simulated sequence in {seq_dir}")
    ready = prepare(settings, Source(seq_dir, name="campus", fmt="kitti"), log=log, progress=progress)
    return DemoInfo(settings, ready.sequence_id, f"http://{settings.host}:{port}/api/v1/docs", ready.admin_token,
                    ready.operator_token, ready.ingest_result)

