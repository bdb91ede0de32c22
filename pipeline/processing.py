"""The orchestrator: a sequence in, per-frame segments, samples and track ids out.

Per frame (in parallel when `workers` > 1):
  1. project the scan to a range image;
  2. estimate the ground and the height above it;
  3. grow segments;
  4. compute segment statistics and the validity rule;
  5. render the samples of valid segments.
Then, in frame order:
  6. associate valid segments with the previous frame's and extend tracks.
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import itertools
import multiprocessing
import os
import tempfile
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

import numba
import numpy as np

from pipeline.association import AssociationFrame, associate
from pipeline.config import PipelineConfig
from pipeline.errors import DataError
from pipeline.frames import FrameResult, FrameSegments
from pipeline.ground import estimate_ground
from pipeline.progress import QUIET, Progress
from pipeline.range_image import project
from pipeline.samples import render_samples, segment_table
from pipeline.scan import Scan, SequenceSource
from pipeline.segmentation import segment
from pipeline.sensors import SensorModel


def _only_valid(ids: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """`ids` (any shape, -1 = none) with the ids of invalid segments replaced by -1."""
    lut = np.append(np.where(valid, np.arange(len(valid)), -1), -1).astype(np.int32)
    return lut[ids]  # id -1 picks the appended -1


def _one_thread_per_worker() -> None:
    """Pool initializer: the workers already use every core, so each one's numba kernels run on
    one thread (more would only oversubscribe the cores)."""
    import numba

    numba.set_num_threads(1)


def process_scan(
    scan: Scan, sensor: SensorModel, config: PipelineConfig, index: int = 0, name: str = "", samples: bool = True
) -> FrameResult:
    """Steps 1–5 for one scan: a FrameResult whose tracking fields are still empty."""
    t0 = time.perf_counter()
    image = project(scan, sensor, config.range_image)
    t1 = time.perf_counter()
    g = estimate_ground(scan, image, config.ground)
    t2 = time.perf_counter()
    seg = segment(image, scan.points, g.ground, sensor, config.segmentation)
    t3 = time.perf_counter()
    table = segment_table(scan.points, seg.point, seg.count, config.samples)
    if samples:
        canv, canv_seg = render_samples(scan, image, g.height, seg.point, table, sensor, config.samples)
    else:
        canv = np.zeros((0, config.samples.channels, config.samples.size, config.samples.size), np.uint8)
        canv_seg = np.zeros(0, np.int32)
    t4 = time.perf_counter()
    # the pixel map association uses only holds valid segments
    valid_pixel = _only_valid(seg.pixel, table.valid)
    timings = {
        "project": 1e3 * (t1 - t0),
        "ground": 1e3 * (t2 - t1),
        "segment": 1e3 * (t3 - t2),
        "samples": 1e3 * (t4 - t3),
    }
    # segmentation takes the feet of objects back from the ground band
    ground = g.ground & (seg.point < 0)
    return FrameResult(
        index, name, scan, seg.point, ground, g.height, valid_pixel.astype(np.int32), image.range,
        FrameSegments(n_points=table.n_points, centroid=table.centroid, range=table.range, valid=table.valid),
        canv, canv_seg, timings_ms=timings,
    )


@dataclass(frozen=True)
class _Spilled:
    """A worker's canvases left in a file for the main process (`path`, mapped once and unlinked)."""

    path: str


def _load_and_process(args: tuple) -> FrameResult | DataError:
    source, index, sensor, config, samples, spill_dir = args
    try:
        scan = source.frame(index)
    except DataError as exc:
        return exc
    core = process_scan(scan, sensor, config, index, source.frame_name(index), samples)
    if spill_dir is not None and core.samples.size:
        # a frame's 256x256 canvases are tens of MB: pickled through the pool's pipe they cost the
        # main process more than rendering them cost the worker, so they go through a file
        # (in memory where /dev/shm exists) instead
        path = os.path.join(spill_dir, f"{index}.npy")
        try:
            np.save(path, core.samples)
        except OSError:  # the file system is full: send them through the pipe after all
            with contextlib.suppress(OSError):
                os.unlink(path)
            return core
        core = dataclasses.replace(core, samples=_Spilled(path))  # type: ignore[arg-type]
    return core


def _ordered(pool: ProcessPoolExecutor, jobs: list[tuple], ahead: int) -> Iterator[FrameResult | DataError]:
    """`_load_and_process` over `jobs` on `pool`, results in job order, at most `ahead` frames in
    flight or waiting (the workers may not run arbitrarily far ahead of the association, each
    finished frame holds its scan and canvases)."""
    pending: collections.deque = collections.deque()
    it = iter(jobs)
    try:
        for job in itertools.islice(it, ahead):
            pending.append(pool.submit(_load_and_process, job))
        while pending:
            result = pending.popleft().result()
            job = next(it, None)
            if job is not None:
                pending.append(pool.submit(_load_and_process, job))
            yield result
    finally:
        for fut in pending:
            fut.cancel()


def _unspill(core: FrameResult) -> FrameResult:
    if not isinstance(core.samples, _Spilled):
        return core
    path = core.samples.path
    # mapped, not read: no copy here; copy-on-write, so the array is writable like any other, and
    # the unlinked file's memory is freed with the array
    canvases = np.load(path, mmap_mode="c")
    os.unlink(path)
    return dataclasses.replace(core, samples=canvases)


def _spill_root() -> str | None:
    """/dev/shm where it exists and is writable (a RAM file system), else the default temp folder."""
    shm = "/dev/shm"
    return shm if os.path.isdir(shm) and os.access(shm, os.W_OK) else None


class SequenceProcessor:
    """Runs the pipeline over a sequence and assigns global track ids.

    Without poses every valid segment becomes its own one-frame track (`linked` is False).
    Corrupt frames are skipped and reported through `on_skip(index, error)`.
    """

    def __init__(self, config: PipelineConfig, sensor: SensorModel) -> None:
        self.config = config
        self.sensor = sensor
        self.next_track = 1
        self.linked = True

    def iter_frames(
        self,
        source: SequenceSource,
        progress: Progress = QUIET,
        workers: int = 1,
        start: int = 0,
        stop: int | None = None,
        samples: bool = True,
        poses: np.ndarray | None = None,
        on_skip: Callable[[int, DataError], None] | None = None,
    ) -> Iterator[FrameResult]:
        """Yield a FrameResult per frame in order; `poses` overrides the source's own."""
        poses = source.poses if poses is None else poses
        self.linked = poses is not None
        stop = len(source) if stop is None else min(stop, len(source))
        times = source.times
        spill = tempfile.TemporaryDirectory(prefix="tracklabel-", dir=_spill_root()) if workers > 1 else None
        jobs = [(source, i, self.sensor, self.config, samples, spill.name if spill else None)
                for i in range(start, stop)]
        prev: AssociationFrame | None = None
        prev_tracks = np.zeros(0, np.int64)
        prev_vel = np.zeros((0, 3))
        bar = progress.bar(len(jobs), "process")
        if workers > 1:
            # forkserver, not fork: the stages' numba kernels run on a thread pool (OpenMP where
            # numba finds it), and a child forked from a process that has started GNU OpenMP
            # aborts when it runs a parallel kernel. As with any spawned pool, a script that calls
            # this needs the `if __name__ == "__main__":` guard.
            ctx = multiprocessing.get_context("forkserver")
            ctx.set_forkserver_preload([__name__])  # the server imports the stages once, workers inherit them
            pool = ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_one_thread_per_worker)
            results = _ordered(pool, jobs, ahead=4 * workers)
        else:
            pool = None
            results = map(_load_and_process, jobs)
        threads_before = numba.get_num_threads()
        if pool is None:
            # one numba thread per frame: two threads are 25 % faster on an idle 2-core machine
            # but 1.6-20x slower whenever the other core is busy (docs/perception.md);
            # --workers parallelises instead
            numba.set_num_threads(1)
        try:
            for job, core in zip(jobs, results, strict=True):
                i = job[1]
                bar.update()
                if isinstance(core, DataError):
                    if on_skip is not None:
                        on_skip(i, core)
                    prev = None  # do not link across a missing frame
                    continue
                core = _unspill(core)
                T = None if poses is None else np.asarray(poses[i], dtype=np.float64)
                t_s = float(times[i]) if times is not None else i / self.sensor.frequency_hz
                t0 = time.perf_counter()
                fr, prev, prev_tracks, prev_vel = self._track(core, T, t_s, prev, prev_tracks, prev_vel)
                fr.timings_ms["associate"] = 1e3 * (time.perf_counter() - t0)
                yield fr
        finally:
            numba.set_num_threads(threads_before)
            bar.close()
            if pool is not None:
                pool.shutdown(cancel_futures=True)
            if spill is not None:
                spill.cleanup()

    def _track(
        self,
        core: FrameResult,
        T: np.ndarray | None,
        t_s: float,
        prev: AssociationFrame | None,
        prev_tracks: np.ndarray,
        prev_vel: np.ndarray,
    ) -> tuple[FrameResult, AssociationFrame, np.ndarray, np.ndarray]:
        table = core.segments
        n = len(table)
        cw = table.centroid.astype(np.float64)
        if T is not None:
            cw = cw @ T[:3, :3].T + T[:3, 3]
        curr = AssociationFrame(core.seg_pixel, core.range_pixels, table.n_points, cw, table.valid, T, t_s)
        track_id = np.zeros(n, np.int64)
        score = np.full(n, np.nan, np.float32)
        vel = np.zeros((n, 3))
        matched = np.full(n, -1, np.int32)
        fragments, fragment_share = np.zeros((0, 2), np.int32), np.zeros(0, np.float32)
        if prev is not None and T is not None:
            valid_point = _only_valid(core.segment, table.valid)
            links = associate(
                core.scan.points, valid_point, curr, prev, prev_vel, self.sensor, self.config.association
            )
            matched = links.prev
            score = links.score
            fragments, fragment_share = links.fragments, links.fragment_share
        has = matched >= 0
        track_id[has] = prev_tracks[matched[has]]
        dt = max(t_s - (prev.time if prev is not None else t_s - 0.1), 1e-3)
        if has.any() and prev is not None:
            meas = (cw[has] - prev.centroid_world[matched[has]]) / dt
            old = prev_vel[matched[has]]
            vel[has] = np.where(np.linalg.norm(old, axis=1, keepdims=True) > 0, 0.5 * old + 0.5 * meas, meas)
        new = table.valid & ~has
        track_id[new] = np.arange(self.next_track, self.next_track + int(new.sum()))
        self.next_track += int(new.sum())
        segs = FrameSegments(
            n_points=table.n_points, centroid=table.centroid, range=table.range, valid=table.valid,
            centroid_world=cw, track_id=track_id, link_score=score,
        )
        fr = dataclasses.replace(
            core, segments=segs, T_world_lidar=T, time=t_s, timings_ms=dict(core.timings_ms), fragments=fragments,
            fragment_share=fragment_share,
        )
        return fr, curr, track_id, vel
