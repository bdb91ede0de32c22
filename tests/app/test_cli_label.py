"""`tracklabel label / train / export` on a small simulated sequence, without serving: the
user's path from a recording to labels and a model (the browser walks it in
tests/annotator_ui/test_browser_label.py)."""

from __future__ import annotations

import json
import socket
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from typer.testing import CliRunner

from app.cli import app
from app.core.config import Settings, default_data_dir
from app.main import create_app
from pipeline.classes import SEMANTICKITTI_WRITE_ID

runner = CliRunner()


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    from research.simulation import simulate_sequence

    out = tmp_path_factory.mktemp("rec") / "my_drive"
    simulate_sequence(out, frames=4, seed=3)
    return out


@pytest.fixture(scope="module")
def labelled(recording, tmp_path_factory) -> Path:
    """A data folder where `label` ingested the recording (no serving)."""
    data = tmp_path_factory.mktemp("data")
    r = runner.invoke(app, ["label", str(recording), "--data-dir", str(data), "--no-serve"])
    assert r.exit_code == 0, r.output
    return data


def review(data: Path, classes: list[str]) -> list[int]:
    """Label the next len(classes) tracks as the local admin would in the annotator."""
    r = runner.invoke(app, ["user", "token", "admin"], env={"TRACKLABEL_DATA_DIR": str(data)})
    headers = {"Authorization": f"Bearer {r.output.strip()}"}
    ids = []
    with TestClient(create_app(Settings(data_dir=data, embedded_worker=False))) as c:
        for name in classes:
            track = c.post("/api/v1/review/next", headers=headers).json()
            body = {"version": track["version"], "label": name}
            assert c.post(f"/api/v1/tracks/{track['id']}/label", json=body, headers=headers).status_code == 200
            ids.append(track["id"])
    return ids


def test_label_busy_port_exits_2_before_any_work(recording, tmp_path):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        busy = s.getsockname()[1]
        r = runner.invoke(app, ["label", str(recording), "--data-dir", str(tmp_path / "d"), "--port", str(busy)])
        assert r.exit_code == 2 and f"port {busy}" in r.output and "--port" in r.output, r.output
        r = runner.invoke(app, ["demo", "--out", str(tmp_path / "demo"), "--viewer-port", str(busy)])
        assert r.exit_code == 2 and "--viewer-port" in r.output, r.output
    assert not (tmp_path / "d").exists() and not (tmp_path / "demo").exists()


def test_label_prints_the_data_folder_and_ingests(recording, tmp_path):
    data = tmp_path / "d"
    r = runner.invoke(app, ["label", str(recording), "--data-dir", str(data), "--no-serve"])
    assert r.exit_code == 0, r.output
    assert f"data: {data.resolve()}" in r.output.splitlines()[0]
    assert "4 frames" in r.output and "admin token:    tl_" in r.output and "operator token: tl_" in r.output
    again = runner.invoke(app, ["label", str(recording), "--data-dir", str(data), "--no-serve"])
    assert again.exit_code == 0 and "already ingested" in again.output and "registered before" in again.output


def test_default_data_folder_is_per_user_not_per_working_folder(monkeypatch, tmp_path):
    monkeypatch.delenv("TRACKLABEL_DATA_DIR", raising=False)
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "xdg"))
    monkeypatch.chdir(tmp_path)
    assert Settings().data_dir == default_data_dir() == tmp_path / "xdg" / "tracklabel"
    monkeypatch.delenv("XDG_DATA_HOME")
    assert default_data_dir() == Path.home() / ".local" / "share" / "tracklabel"


def test_label_registers_the_recording_with_its_label_set(recording, tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: campus\nclasses:\n  - {name: walker, colour: [1, 2, 300], writes: 30, reads: [30], kind: thing}\n")
    r = runner.invoke(app, ["label", str(recording), "--data-dir", str(tmp_path / "d"), "--no-serve", "--label-set", str(bad)])
    assert r.exit_code == 2 and "bad.yaml: field classes.0 (walker).colour.2" in r.output, r.output
    data = tmp_path / "d2"
    r = runner.invoke(app, ["label", str(recording), "--data-dir", str(data), "--no-serve", "--label-set", "nuscenes"])
    assert r.exit_code == 0 and "label set nuscenes" in r.output, r.output
    token = runner.invoke(app, ["user", "token", "admin"], env={"TRACKLABEL_DATA_DIR": str(data)}).output.strip()
    with TestClient(create_app(Settings(data_dir=data, embedded_worker=False))) as c:
        seqs = c.get("/api/v1/sequences", headers={"Authorization": f"Bearer {token}"}).json()
    assert [s["label_set"] for s in seqs] == ["nuscenes"]
    again = runner.invoke(app, ["label", str(recording), "--data-dir", str(data), "--no-serve", "--label-set", "paper"])
    assert again.exit_code == 2 and "was registered with label set 'nuscenes'" in again.output, again.output


def test_label_unknown_path_exits_2(tmp_path):
    r = runner.invoke(app, ["label", str(tmp_path / "nope"), "--data-dir", str(tmp_path / "d"), "--no-serve"])
    assert r.exit_code == 2 and "nope" in r.output


def test_train_and_export_name_the_registered_sequences_when_seq_is_unknown(labelled, tmp_path):
    for cmd in (["train", str(tmp_path)], ["export", str(tmp_path), "--out", str(tmp_path / "o")]):
        r = runner.invoke(app, [*cmd, "--data-dir", str(labelled)])
        assert r.exit_code == 2 and "my_drive" in r.output, r.output


def test_train_without_reviews_exits_2(labelled, recording):
    r = runner.invoke(app, ["train", str(recording), "--data-dir", str(labelled), "--model-size", "tiny"])
    assert r.exit_code == 2 and "no labels" in r.output, r.output


def test_review_train_predict_export(labelled, recording, tmp_path, monkeypatch):
    classes = ["car", "building", "bush", "car", "building", "bush", "trunk", "car"]
    review(labelled, classes)
    r = runner.invoke(app, ["train", str(recording), "--data-dir", str(labelled), "--model-size", "tiny",
                            "--epochs", "1", "--steps-per-epoch", "3"])
    assert r.exit_code == 0, r.output
    ckpt = Path(r.output.strip().splitlines()[-1].removeprefix("checkpoint: "))
    assert ckpt.is_file() and labelled in ckpt.parents

    monkeypatch.setenv("TRACKLABEL_DATA_DIR", str(labelled))
    r = runner.invoke(app, ["predict", str(recording), "--out", str(tmp_path / "pred"), "--model", "latest"])
    assert r.exit_code == 0 and f"model: {ckpt}" in r.output, r.output
    assert json.loads((tmp_path / "pred" / "summary.json").read_text())["frames_scored"] == 4

    reviewed = {SEMANTICKITTI_WRITE_ID[c] for c in classes}
    for extra, check in (([], reviewed.issubset), (["--reviewed-only"], ({0} | reviewed).__eq__)):
        out = tmp_path / f"x{len(extra)}"
        r = runner.invoke(app, ["export", str(recording), "--out", str(out), *extra])
        assert r.exit_code == 0, r.output
        files = sorted((out / "sequences" / "my_drive" / "labels").glob("*.label"))
        assert len(files) == 4 and (out / "sequences" / "my_drive" / "summary.json").is_file()
        ids = set(np.unique(np.concatenate([np.fromfile(f, np.uint32) & 0xFFFF for f in files])).tolist())
        assert check(ids), (extra, ids)
