"""The service under test, and the REST calls the benchmark makes to it.

`LocalService` starts `tracklabel serve` (API + job worker, no viewer) on SQLite in a temporary
folder, with its users made by `tracklabel user add`. `Api` is a thin client over the REST API:
what a person at the viewer, a reviewer and an admin's script call.
"""

from __future__ import annotations

import io
import json
import os
import socket
import subprocess
import sys
import tarfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import numpy as np

from pipeline.label_sets import DEFAULT_LABEL_SET

CLI = [sys.executable, "-c", "from app.cli import main; main()"]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class LocalService:
    """`tracklabel serve` in a subprocess over `data_dir`, sequences allowed under `roots`."""

    def __init__(self, data_dir: Path, roots: list[Path], env: dict[str, str] | None = None) -> None:
        self.data_dir = data_dir
        self.port = _free_port()
        self.env = {**os.environ, "TRACKLABEL_DATA_DIR": str(data_dir),
                    "TRACKLABEL_DATA_ROOTS": ",".join(str(r) for r in roots), **(env or {})}
        self.proc: subprocess.Popen[bytes] | None = None
        self.log = data_dir / "service.log"

    def user(self, name: str, role: str) -> str:
        out = subprocess.run([*CLI, "user", "add", name, "--role", role], env=self.env, check=True,
                             capture_output=True, text=True)
        return out.stdout.strip().splitlines()[-1]

    def __enter__(self) -> LocalService:
        self.data_dir.mkdir(parents=True, exist_ok=True)
        with open(self.log, "wb") as log:
            self.proc = subprocess.Popen([*CLI, "serve", "--port", str(self.port), "--no-viewer"], env=self.env,
                                         stdout=log, stderr=subprocess.STDOUT)
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"the service exited: {self.log.read_text()[-2000:]}")
            try:
                if httpx.get(f"{self.url}/health", timeout=2).status_code == 200:
                    return self
            except httpx.HTTPError:
                time.sleep(0.5)
        raise RuntimeError("the service did not start within 120 s")

    def __exit__(self, *exc: object) -> None:
        if self.proc is not None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self.proc.kill()

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}/api/v1"


@dataclass(frozen=True)
class FrameInfo:
    id: int
    index: int
    name: str
    T_world_lidar: np.ndarray


@dataclass(frozen=True)
class Export:
    """An export: per frame name its uint32 words and uint8 sources, the summary, the tar itself."""

    labels: dict[str, np.ndarray]
    sources: dict[str, np.ndarray]
    summary: dict[str, Any]
    tar: bytes

    @classmethod
    def read(cls, folder: Path) -> Export:
        """The export a benchmark run kept (OUT/export: labels/, sources/, summary.json)."""
        return cls({p.stem: np.fromfile(p, np.uint32) for p in sorted((folder / "labels").glob("*.label"))},
                   {p.stem: np.fromfile(p, np.uint8) for p in sorted((folder / "sources").glob("*.source"))},
                   json.loads((folder / "summary.json").read_text()), b"")


class Api:
    """REST calls as one user. `client` is any httpx client whose base URL is the API root."""

    def __init__(self, client: httpx.Client, token: str) -> None:
        self.client = client
        self.headers = {"Authorization": f"Bearer {token}"}

    def _call(self, method: str, path: str, ok: tuple[int, ...] = (200,), **kw: Any) -> httpx.Response:
        r = self.client.request(method, path, headers=self.headers, **kw)
        if r.status_code not in ok:
            raise RuntimeError(f"{method} {path}: {r.status_code} {r.text[:500]}")
        return r

    def get(self, path: str, **kw: Any) -> Any:
        return self._call("GET", path, **kw).json()

    def post(self, path: str, body: dict[str, Any] | None = None, ok: tuple[int, ...] = (200,), **kw: Any) -> Any:
        r = self._call("POST", path, ok=ok, json=body, **kw)
        return r.json() if r.content else None

    def register(self, path: Path, label_set: str = DEFAULT_LABEL_SET) -> int:
        ds = self.post("/datasets", {"path": str(path), "label_set": label_set}, ok=(201,))
        return int(ds["sequences"][0]["id"])

    def wait_ready(self, sequence_id: int, timeout: float = 3600.0) -> dict[str, Any]:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            seq = self.get(f"/sequences/{sequence_id}")
            if seq["status"] in ("ready", "failed"):
                if seq["status"] == "failed":
                    raise RuntimeError(f"ingest of sequence {sequence_id} failed: {seq}")
                return seq
            time.sleep(1.0)
        raise RuntimeError(f"sequence {sequence_id} was not ready within {timeout:g} s")

    def wait_jobs_idle(self, job_type: str, timeout: float = 600.0, settle: float = 0.0) -> float:
        """Wait until no job of `job_type` is queued or running, seen twice `settle` seconds
        apart (a worker that polls more often than that has queued what it would); returns the
        seconds waited."""
        t0 = time.monotonic()
        idle_since: float | None = None
        while time.monotonic() - t0 < timeout:
            busy = [j for st in ("queued", "running") for j in self.get("/jobs", params={"status": st, "type": job_type})]
            now = time.monotonic()
            if busy:
                idle_since = None
            elif idle_since is None:
                idle_since = now
            if idle_since is not None and now - idle_since >= settle:
                return now - t0
            time.sleep(min(0.2, settle) if idle_since is not None else 0.5)
        raise RuntimeError(f"{job_type} jobs still busy after {timeout:g} s")

    def frames(self, sequence_id: int) -> list[FrameInfo]:
        items = self.get(f"/sequences/{sequence_id}/frames", params={"limit": 10000})["items"]
        return [FrameInfo(f["id"], f["index"], f["name"],
                          np.eye(4) if f["pose"] is None else np.asarray(f["pose"], np.float64).reshape(4, 4))
                for f in items]

    def payload(self, frame_id: int) -> dict[str, np.ndarray]:
        r = self._call("GET", f"/frames/{frame_id}/payload")
        with np.load(io.BytesIO(r.content)) as z:
            return {k: z[k] for k in z.files}

    def export(self, sequence_id: int, **params: Any) -> Export:
        """The SemanticKITTI export (with each point's source)."""
        r = self._call("GET", f"/exports/semantickitti/{sequence_id}", params={**params, "with_sources": True})
        tar = tarfile.open(fileobj=io.BytesIO(r.content))
        out = Export({}, {}, {}, r.content)
        for member in tar.getmembers():
            data = tar.extractfile(member).read()  # type: ignore[union-attr]
            if member.name.endswith(".label"):
                out.labels[Path(member.name).stem] = np.frombuffer(data, np.uint32)
            elif member.name.endswith(".source"):
                out.sources[Path(member.name).stem] = np.frombuffer(data, np.uint8)
            elif member.name.endswith("summary.json"):
                out.summary.update(json.loads(data))
        return out
