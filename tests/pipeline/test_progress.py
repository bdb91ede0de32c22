from __future__ import annotations

from pipeline.progress import QUIET, TqdmProgress


def test_progress_quiet_iterates_without_output(capsys):
    assert list(QUIET.iterate(range(3), "x")) == [0, 1, 2]
    with QUIET.bar(5, "x") as bar:
        bar.update()
        bar.set_postfix(loss="1")
    assert capsys.readouterr() == ("", "")


def test_progress_tqdm_draws_a_bar_on_stderr(capsys):
    assert list(TqdmProgress().iterate(["a", "b"], "stage", unit="item")) == ["a", "b"]
    err = capsys.readouterr().err
    assert "stage" in err and "2/2" in err
