from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from app.cli import app

runner = CliRunner()


@pytest.fixture(scope="module")
def sim(tmp_path_factory) -> Path:
    from research.simulation import simulate_sequence

    out = tmp_path_factory.mktemp("sim") / "seq"
    simulate_sequence(out, frames=6, seed=3)
    return out


def test_cli_process_writes_track_labels_json_and_summary(sim, tmp_path):
    out = tmp_path / "out"
    res = runner.invoke(app, ["process", str(sim), "--out", str(out), "--samples"])
    assert res.exit_code == 0, res.output
    summary = json.loads((out / "summary.json").read_text())
    assert summary["frames"] == 6 and summary["linked"]
    assert summary["ms_project_ground_segment"]["median"] > 0
    doc = json.loads((out / "tracks.json").read_text())
    tracks = doc["tracks"]
    assert any(len(t["frames"]) == 6 for t in tracks)
    # stitches join two different tracks that exist in consecutive frames
    frames_of = {t["id"]: set(t["frames"]) for t in tracks}
    assert summary["stitches"] == len(doc["stitches"]) > 0
    for st in doc["stitches"]:
        a, b = st["tracks"]
        assert a < b and st["links"] >= 1 and 0.3 <= st["share"] <= 1.0
        assert any(f + 1 in frames_of[b] or f - 1 in frames_of[b] for f in frames_of[a])
    for t in tracks:
        assert len(t["scores"]) == len(t["frames"]) - 1
        assert t["frames"] == list(range(t["frames"][0], t["frames"][0] + len(t["frames"])))
    scan_sizes = [p.stat().st_size for p in sorted((sim / "velodyne").glob("*.bin"))]
    labels = [np.fromfile(p, np.uint32) for p in sorted((out / "tracks").glob("*.label"))]
    assert [4 * len(lab) for lab in labels] == [s // 4 for s in scan_sizes]
    # one segment per track per frame: every id of a frame is a track present in that frame
    for i, lab in enumerate(labels):
        ids = set(np.unique(lab[lab > 0]).tolist())
        assert ids == {t["id"] for t in tracks if i in t["frames"]}
    npz = np.load(out / "samples" / "000000.npz")
    assert npz["samples"].dtype == np.uint8 and npz["samples"].shape[1:] == (4, 64, 64)
    assert len(npz["track_id"]) == len(npz["samples"])


def test_cli_process_two_workers_match_one_worker_after_kernels_ran_here(sim, tmp_path):
    # the parallel numba kernels have run in this process already (the tests above); a worker pool
    # started from it must still run them (GNU OpenMP aborts a forked child that does) and must
    # give the same track labels and samples as the single-process run (the workers hand their
    # canvases over through files, which are gone afterwards)
    import tempfile

    from pipeline.processing import _spill_root

    root = Path(_spill_root() or tempfile.gettempdir())
    before = set(root.glob("tracklabel-*"))
    one, two = tmp_path / "one", tmp_path / "two"
    assert runner.invoke(app, ["process", str(sim), "--out", str(one), "--samples"]).exit_code == 0
    res = runner.invoke(app, ["process", str(sim), "--out", str(two), "--workers", "2", "--samples"])
    assert res.exit_code == 0, res.output
    for a in sorted((one / "tracks").glob("*.label")):
        assert np.array_equal(np.fromfile(a, np.uint32), np.fromfile(two / "tracks" / a.name, np.uint32))
    for a in sorted((one / "samples").glob("*.npz")):
        with np.load(a) as x, np.load(two / "samples" / a.name) as y:
            assert len(x["samples"]) and np.array_equal(x["samples"], y["samples"])
    assert set(root.glob("tracklabel-*")) == before


def test_cli_evaluate_reports_purity_and_association(sim, tmp_path):
    out = tmp_path / "out"
    assert runner.invoke(app, ["process", str(sim), "--out", str(out)]).exit_code == 0
    res = runner.invoke(app, ["evaluate", str(sim), str(out)])
    assert res.exit_code == 0, res.output
    metrics = json.loads((out / "evaluation.json").read_text())
    assert metrics["overall"]["purity"] > 0.95
    assert metrics["overall"]["association_precision"] > 0.95
    assert "purity" in res.output and "per class" in res.output
    st = metrics["stitches"]
    assert st["stitches"] > 0 and 0.5 < st["same_object"] <= st["same_class"] <= 1.0
    assert "stitches:" in res.output


def test_cli_process_without_poses_says_so_and_makes_one_frame_tracks(sim, tmp_path):
    seq = tmp_path / "noposes"
    shutil.copytree(sim, seq)
    (seq / "poses.txt").unlink()
    out = tmp_path / "out"
    res = runner.invoke(app, ["process", str(seq), "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert "no poses" in res.output
    tracks = json.loads((out / "tracks.json").read_text())["tracks"]
    assert tracks and all(len(t["frames"]) == 1 for t in tracks)


def test_cli_process_skips_a_corrupt_frame_by_name(sim, tmp_path):
    seq = tmp_path / "corrupt"
    shutil.copytree(sim, seq)
    bad = seq / "velodyne" / "000002.bin"
    bad.write_bytes(bad.read_bytes()[:-3])
    (seq / "labels" / "000002.label").unlink(missing_ok=True)
    out = tmp_path / "out"
    res = runner.invoke(app, ["process", str(seq), "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert "000002" in res.output
    summary = json.loads((out / "summary.json").read_text())
    assert summary["frames"] == 5 and summary["skipped"][0]["frame"] == "000002"


def test_cli_process_unknown_folder_exits_2(tmp_path):
    (tmp_path / "x.txt").write_text("hello")
    res = runner.invoke(app, ["process", str(tmp_path), "--out", str(tmp_path / "o")])
    assert res.exit_code == 2 and "unknown folder layout" in res.output
