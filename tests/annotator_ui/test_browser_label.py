"""The README's "Label your own recording", end to end on real scans: `tracklabel label SEQ`
(a process of its own, as the user starts it) serves five frames of SemanticKITTI 00; chromium
reviews tracks in the annotator with the number keys; then `tracklabel train` (a tiny config),
`tracklabel predict --model latest` and `tracklabel export` run as commands on the same data
folder. Skips without chromium or ../shared/data/real."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import httpx
import numpy as np
import pytest

from pipeline.classes import SEMANTICKITTI_WRITE_ID
from tests.annotator_ui.conftest import free_port
from tests.annotator_ui.test_browser import (
    ARGS,
    CANVAS,
    CHROMIUM,
    TRACK_TEXT,
    shown_track_id,
    wait_for_new_track,
)

pytestmark = [pytest.mark.browser, pytest.mark.real_data,
              pytest.mark.skipif(CHROMIUM is None, reason="chromium is absent")]

FRAMES = 5
KEYS = {"2": "car", "6": "building", "5": "bush"}  # the annotator's number keys


@pytest.fixture
def recording(real_data: Path, tmp_path: Path) -> Path:
    """Frames 0-4 of kitti_seq00 as a KITTI folder of links, with their poses, times and labels."""
    src, seq = real_data / "kitti_seq00", tmp_path / "kitti_seq00_head"
    for sub in ("velodyne", "labels"):
        (seq / sub).mkdir(parents=True)
        for f in sorted((src / sub).iterdir())[:FRAMES]:
            (seq / sub / f.name).symlink_to(f)
    for name in ("poses.txt", "times.txt"):
        (seq / name).write_text("".join((src / name).read_text().splitlines(keepends=True)[:FRAMES]))
    (seq / "calib.txt").symlink_to(src / "calib.txt")
    return seq


def tracklabel(*args: str, env: dict[str, str], timeout: float = 300) -> str:
    r = subprocess.run([sys.executable, "-m", "app.cli", *args], env=env, capture_output=True, text=True, timeout=timeout)
    assert r.returncode == 0, r.stdout + r.stderr
    return r.stdout


@pytest.fixture
def labelling(recording: Path, tmp_path: Path):
    """`tracklabel label SEQ` running; yields (viewer URL, API URL, admin token, env)."""
    env = {**os.environ, "TRACKLABEL_DATA_DIR": str(tmp_path / "data")}
    port, vport = free_port(), free_port()
    log = (tmp_path / "label.log").open("w")
    proc = subprocess.Popen([sys.executable, "-m", "app.cli", "label", str(recording), "--port", str(port),
                             "--viewer-port", str(vport)], env=env, stdout=log, stderr=subprocess.STDOUT, text=True)
    api = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 240
        while not _answers(f"{api}/api/v1/health") or not _answers(f"http://127.0.0.1:{vport}"):
            assert proc.poll() is None and time.monotonic() < deadline, (tmp_path / "label.log").read_text()
            time.sleep(0.5)
        out = (tmp_path / "label.log").read_text()
        token = next(line.split()[-1] for line in out.splitlines() if line.startswith("admin token:"))
        assert f"data: {tmp_path / 'data'}" in out
        yield f"http://127.0.0.1:{vport}", api, token, env
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
        log.close()


def _answers(url: str) -> bool:
    try:
        return httpx.get(url, timeout=2).status_code == 200
    except httpx.HTTPError:
        return False


def review_with_keys(viewer_url: str, api: str, token: str) -> dict[int, str]:
    """Label six tracks with the number keys; the class given to each track id."""
    sync_api = pytest.importorskip("playwright.sync_api")
    given: dict[int, str] = {}
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        page = browser.new_page(viewport={"width": 1280, "height": 800})
        errors: list[str] = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.goto(viewer_url)
        page.wait_for_selector(CANVAS, timeout=60_000)
        page.get_by_text(TRACK_TEXT).first.wait_for(timeout=60_000)
        for key in [*KEYS, *KEYS]:
            tid = shown_track_id(page)
            page.keyboard.press(key)
            given[tid] = KEYS[key]
            wait_for_new_track(page, tid, timeout=30)
        browser.close()
    assert not errors, errors
    headers = {"Authorization": f"Bearer {token}"}
    for tid, cls in given.items():
        track = httpx.get(f"{api}/api/v1/tracks/{tid}", headers=headers, timeout=30).json()
        assert (track["status"], track["label"]) == ("accepted", cls), tid
    return given


def test_browser_label_your_own_recording(labelling, recording, tmp_path):
    viewer_url, api, token, env = labelling
    given = review_with_keys(viewer_url, api, token)

    out = tracklabel("train", str(recording), "--model-size", "tiny", "--epochs", "1", "--steps-per-epoch", "3", env=env)
    checkpoint = Path(out.strip().splitlines()[-1].removeprefix("checkpoint: "))
    assert checkpoint.is_file()

    out = tracklabel("predict", str(recording), "--out", str(tmp_path / "pred"), "--model", "latest", env=env)
    summary = json.loads((tmp_path / "pred" / "summary.json").read_text())
    assert summary["model"] == str(checkpoint) and summary["frames"] == FRAMES and summary["frames_scored"] == FRAMES
    assert f"the {FRAMES} of {FRAMES} frames that have labels" in out

    tracklabel("export", str(recording), "--out", str(tmp_path / "export"), env=env)
    files = sorted((tmp_path / "export" / "sequences" / recording.name / "labels").glob("*.label"))
    assert [f.name for f in files] == [f"{i:06d}.label" for i in range(FRAMES)]
    for f in files:  # one label per point of the scan
        assert f.stat().st_size == (recording / "velodyne" / f"{f.stem}.bin").stat().st_size // 4
    semantic = np.concatenate([np.fromfile(f, np.uint32) & 0xFFFF for f in files])
    assert {SEMANTICKITTI_WRITE_ID[c] for c in given.values()} <= set(np.unique(semantic).tolist())
    assert (tmp_path / "export" / "sequences" / recording.name / "summary.json").is_file()
