"""The job workers `tracklabel serve` starts beside the API: separate processes, so that no job
shares the API's event loop, GIL or memory (a training job in the API process stalled every
request). Each is `python -m app.cli worker` with the same environment; one that exits is started
again after a pause (the database may still be starting, or a job may have crashed it)."""

from __future__ import annotations

import logging
import os
import subprocess
import sys
import threading

log = logging.getLogger("tracklabel.serve")
RESTART_PAUSE_S = 5.0


def _die_with_parent() -> None:
    """In the child, Linux only: SIGTERM when the API process dies, even by SIGKILL."""
    if sys.platform.startswith("linux"):
        import ctypes
        import signal

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG


class WorkerProcesses:
    def __init__(self, count: int, env: dict[str, str] | None = None) -> None:
        self.count = count
        self.env = {**os.environ, **(env or {})}  # settings the API got otherwise than from the environment
        self.procs: list[subprocess.Popen] = []
        self._stop = threading.Event()
        self._watch: threading.Thread | None = None

    def _spawn(self) -> subprocess.Popen:
        return subprocess.Popen([sys.executable, "-m", "app.cli", "worker"], env=self.env, preexec_fn=_die_with_parent)

    def start(self) -> None:
        self.procs = [self._spawn() for _ in range(self.count)]
        self._watch = threading.Thread(target=self._restart_exited, daemon=True, name="worker-watch")
        self._watch.start()

    def _restart_exited(self) -> None:
        while not self._stop.wait(RESTART_PAUSE_S):
            for i, proc in enumerate(self.procs):
                if proc.poll() is not None and not self._stop.is_set():
                    log.warning("job worker %d exited with %s; starting it again", proc.pid, proc.returncode)
                    self.procs[i] = self._spawn()

    def stop(self, timeout_s: float = 15.0) -> None:
        """SIGTERM each worker (it finishes its current checkpoint), then wait; kill stragglers."""
        self._stop.set()
        for proc in self.procs:
            if proc.poll() is None:
                proc.terminate()
        for proc in self.procs:
            try:
                proc.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
