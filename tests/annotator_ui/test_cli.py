"""`tracklabel annotate`: starts against a live API, and refuses cleanly (exit 2) when it cannot."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from pathlib import Path

import httpx
from typer.testing import CliRunner

from app.cli import app as cli
from tests.annotator_ui.conftest import free_port

REPO = Path(__file__).resolve().parents[2]


def test_cli_annotate_unreachable_api_exits_2():
    port = free_port()
    r = CliRunner().invoke(cli, ["annotate", "--api", f"http://127.0.0.1:{port}", "--wait", "0.5"])
    assert r.exit_code == 2 and "did not answer" in r.output


def test_cli_annotate_refused_token_exits_2(live_api):
    r = CliRunner().invoke(cli, ["annotate", "--api", live_api.url, "--token", "tl_not_a_token", "--wait", "5"])
    assert r.exit_code == 2 and "refused" in r.output


def test_cli_annotate_serves_the_viewer(live_api):
    proc = subprocess.Popen(
        [sys.executable, "-m", "app.cli", "annotate", "--api", live_api.url, "--token", live_api.new_operator(),
         "--port", "0"],
        cwd=REPO, env={**os.environ, "PYTHONUNBUFFERED": "1"}, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )
    try:
        deadline = time.monotonic() + 60
        url = None
        while url is None:
            line = proc.stdout.readline()
            assert line or proc.poll() is None, "annotate exited"
            m = re.search(r"annotator (http://\S+)", line)
            url = m.group(1) if m else None
            assert time.monotonic() < deadline
        r = httpx.get(url)
        assert r.status_code == 200 and "<html" in r.text.lower()
    finally:
        proc.terminate()
        proc.wait(timeout=10)
