"""A headless viser client: connects to the viewer over its websocket exactly as a browser tab
does (same subprotocol, same wire format), records what the server sends, and triggers commands as
a key press would. Used by the benchmark (latency, 4 connected clients) and by tests that need a
real connected client without a browser.

Wire format (viser 1.x, server -> client): [u64 msgpack size][u64 zstd size][zstd(msgpack)]
[padding to 8][binary buffers]; the msgpack holds {"messages": [...], "binaryBufferLengths": [...]}
where numpy arrays are placeholders {"__binary_index": i, ...}. Client -> server: plain msgpack.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import msgspec
import viser
import zstandard
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import ClientConnection, connect


@dataclass(frozen=True)
class Received:
    """One message the server sent: arrival time (perf_counter), type, and its fields (arrays as
    {"__binary_index", "nbytes"} placeholders)."""

    t: float
    type: str
    fields: dict[str, Any]

    @property
    def name(self) -> str | None:
        return self.fields.get("name")


def _resolve_sizes(obj: Any, lengths: list[int]) -> Any:
    if isinstance(obj, dict):
        if "__binary_index" in obj:
            return {**obj, "nbytes": lengths[obj["__binary_index"]]}
        return {k: _resolve_sizes(v, lengths) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_resolve_sizes(v, lengths) for v in obj]
    return obj


def decode_frame(raw: bytes) -> list[dict[str, Any]]:
    """One websocket frame from the server -> its messages (dicts with a "type")."""
    inner_len = int.from_bytes(raw[0:8], "little")
    comp_len = int.from_bytes(raw[8:16], "little")
    inner = zstandard.ZstdDecompressor().decompress(raw[16 : 16 + comp_len], max_output_size=inner_len)
    body = msgspec.msgpack.decode(inner)
    lengths = list(body.get("binaryBufferLengths", ()))
    return [_resolve_sizes(m, lengths) for m in body["messages"]]


class HeadlessClient:
    """A connected viser client in a background thread. `commands` maps label -> uuid."""

    def __init__(self, url: str, timeout: float = 10.0) -> None:
        ws_url = url.replace("http://", "ws://").replace("https://", "wss://")
        self._ws: ClientConnection = connect(
            ws_url, subprotocols=[f"viser-v{viser.__version__}"], max_size=None, open_timeout=timeout  # type: ignore[list-item]
        )
        self.messages: list[Received] = []
        self.commands: dict[str, str] = {}
        self.gui: dict[str, dict[str, Any]] = {}  # uuid -> props of GUI components (label, content, ...)
        self._cond = threading.Condition()
        self._closed = False
        self._thread = threading.Thread(target=self._receive, name="headless-viser", daemon=True)
        self._thread.start()
        # a browser tab counts as connected once it reports its camera; so does this client
        self._send({
            "type": "ViewerCameraMessage", "wxyz": (1.0, 0.0, 0.0, 0.0), "position": (-18.0, -18.0, 16.0),
            "fov": 1.0, "near": 0.01, "far": 1000.0, "image_height": 720, "image_width": 1280,
            "look_at": (0.0, 0.0, 0.0), "up_direction": (0.0, 0.0, 1.0),
        })

    def _send(self, message: dict[str, Any]) -> None:
        self._ws.send(msgspec.msgpack.encode(message))

    def _receive(self) -> None:
        try:
            while True:
                raw = self._ws.recv()
                t = time.perf_counter()
                assert isinstance(raw, bytes)
                msgs = decode_frame(raw)
                with self._cond:
                    for m in msgs:
                        kind = m.pop("type")
                        self.messages.append(Received(t, kind, m))
                        if kind == "RegisterCommandMessage":
                            self.commands[m["props"]["label"]] = m["uuid"]
                        elif kind.startswith("Gui") and "uuid" in m and "props" in m:
                            self.gui[m["uuid"]] = dict(m["props"])
                        elif kind == "GuiUpdateMessage" and m.get("uuid") in self.gui:
                            self.gui[m["uuid"]].update(m.get("updates", {}))
                        elif kind == "LocalStorageGetItemRequestMessage":  # as a browser answers, in order
                            self._send({"type": "LocalStorageGetItemResponseMessage",
                                        "request_uuid": m["request_uuid"], "value": None, "error": None})
                    self._cond.notify_all()
        except (ConnectionClosed, OSError):
            pass
        finally:
            with self._cond:
                self._closed = True
                self._cond.notify_all()

    def wait_for(self, predicate: Callable[[Received], bool], since: int = 0, timeout: float = 30.0) -> Received:
        """The first message at index >= `since` that satisfies `predicate` (waits for it)."""
        deadline = time.monotonic() + timeout
        with self._cond:
            i = since
            while True:
                while i < len(self.messages):
                    if predicate(self.messages[i]):
                        return self.messages[i]
                    i += 1
                left = deadline - time.monotonic()
                if left <= 0 or self._closed:
                    raise TimeoutError("the viewer did not send the expected message")
                self._cond.wait(left)

    def wait_command(self, label: str, timeout: float = 30.0) -> str:
        self.wait_for(lambda m: m.type == "RegisterCommandMessage" and m.fields["props"]["label"] == label,
                      timeout=timeout)
        return self.commands[label]

    def mark(self) -> int:
        """The index the next message will get (pass it as `since`)."""
        with self._cond:
            return len(self.messages)

    def trigger(self, label: str) -> float:
        """Trigger the command `label` as its hotkey would; returns the send time (perf_counter)."""
        uuid = self.commands[label]
        t = time.perf_counter()
        self._send({"type": "CommandTriggerMessage", "uuid": uuid})
        return t

    def markdown_containing(self, text: str) -> str | None:
        """The latest content of a markdown element that contains `text`."""
        with self._cond:
            for props in reversed(list(self.gui.values())):
                content = props.get("_markdown", props.get("content"))
                if isinstance(content, str) and text in content:
                    return content
        return None

    def close(self) -> None:
        try:
            self._ws.close()
        finally:
            self._thread.join(timeout=5)


def is_points(name: str) -> Callable[[Received], bool]:
    """Predicate: a point cloud named `name` arrived (created or replaced)."""
    return lambda m: m.type == "PointCloudMessage" and m.name == name
