"""The paper experiment's spread over runs: each target's mean and range."""

from __future__ import annotations

import json

from typer.testing import CliRunner

from app.cli import app
from research.experiments.spread import ORDER, spread


def _doc(seed: int, label_seed: int | None, f_test: list[float], f_tv: list[float]) -> dict:
    res = {n: {"test": {"mean_f": t}, "train_val": {"mean_f": v}, "val": {"mean_f": v - 1}}
           for n, t, v in zip(ORDER, f_test, f_tv, strict=True)}
    return {"config": {"seed": seed, "label_seed": label_seed, "train_seed": None}, "results": res}


def test_spread_reports_mean_range_and_whether_each_mean_meets_its_target():
    docs = [_doc(0, None, [60, 70, 72, 74, 80], [70, 80, 82, 83, 90]),
            _doc(7301, None, [60, 66, 67, 66, 77], [70, 79, 78, 81, 90])]
    r = spread(docs)
    gain = r["targets"]["gain_on_d"]
    assert gain["values"] == [14.0, 6.0] and gain["mean"] == 10.0 and (gain["min"], gain["max"]) == (6.0, 14.0)
    assert gain["met"]  # the mean meets +10 though one run misses it
    gap = r["targets"]["gap_to_baseline_max_on_d"]
    assert gap["values"] == [6.0, 11.0] and not gap["met"]
    order = r["targets"]["order_train_val"]
    assert order["per_run_met"] == [True, False] and order["met"]  # means 70 < 79.5 < 80 < 82 < 90
    assert r["runs"] == ["scene 0, labels split stream, training 0", "scene 7301, labels split stream, training 7301"]


def test_cli_experiment_spread_writes_json_markdown_and_plot(tmp_path):
    for i, seed in enumerate((0, 5)):
        (tmp_path / f"r{i}").mkdir()
        (tmp_path / f"r{i}" / "paper.json").write_text(json.dumps(_doc(seed, 1, [60, 70, 72, 74, 80], [70, 80, 82, 83, 90])))
    out = tmp_path / "out"
    r = CliRunner().invoke(app, ["experiment", "spread", str(tmp_path / "r0"), str(tmp_path / "r1"), "--out", str(out)])
    assert r.exit_code == 0, r.output
    assert "constraint100 - baseline_min on D: 14.0" in r.output
    assert json.loads((out / "spread.json").read_text())["targets"]["gain_on_d"]["mean"] == 14.0
    assert (out / "spread.png").stat().st_size > 1000
    bad = CliRunner().invoke(app, ["experiment", "spread", str(tmp_path / "nothing"), "--out", str(out)])
    assert bad.exit_code == 2
