"""A tab's frame slider and Play: step through the shown track's frames. When a frame cannot be
drawn (the service is down) the slider and the session go back to the frame still on screen."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import viser

from annotator_ui.review import ReviewSession

PLAY_FPS = 5.0


class Playback:
    def __init__(self, gui: viser.GuiApi, session: ReviewSession, draw: Callable[[], bool], closed: threading.Event,
                 name: str) -> None:
        self.session, self.draw, self.closed, self.name = session, draw, closed, name
        self.gui_frame = gui.add_slider("Frame", min=0, max=1, step=1, initial_value=0, disabled=True)
        self.gui_frame.on_update(self._on_slider)
        self.gui_play = gui.add_button("Play", icon=viser.Icon.PLAYER_PLAY, disabled=True)
        self.gui_play.on_click(lambda _: self.toggle())
        self.playing = threading.Event()
        self._player: threading.Thread | None = None

    def enable(self, on: bool) -> None:
        for h in (self.gui_frame, self.gui_play):
            h.disabled = not on

    def fit(self) -> None:
        """Slider bounds and value to the session's track (call inside the client's atomic())."""
        lo, hi = self.session.frame_range()
        # widen first, so the value always lies inside the bounds
        self.gui_frame.min, self.gui_frame.max = min(lo, self.gui_frame.min), max(hi, self.gui_frame.max)
        self.gui_frame.value = self.session.frame_index
        self.gui_frame.min, self.gui_frame.max = lo, max(hi, lo + 1)  # a 1-frame track keeps a usable slider
        self.gui_frame.disabled = hi == lo

    def _on_slider(self, event: viser.GuiEvent) -> None:
        if event.client is None or self.session.track is None:  # set by the server, already drawn
            return
        self.show(int(self.gui_frame.value))

    def show(self, index: int) -> None:
        shown = self.session.frame_index
        self.session.set_frame(index)
        if not self.draw() and shown is not None:
            self.session.set_frame(shown)
        self.gui_frame.value = self.session.frame_index

    def step(self, delta: int) -> None:
        if self.session.track is None:
            return
        lo, hi = self.session.frame_range()
        idx = self.session.frame_index or lo
        self.show(lo + (idx - lo + delta) % (hi - lo + 1))

    def toggle(self) -> None:
        if self.playing.is_set():
            self.playing.clear()
            return
        if self.session.track is None:
            return
        self.playing.set()
        self.gui_play.label, self.gui_play.icon = "Pause", viser.Icon.PLAYER_PAUSE
        if self._player is None or not self._player.is_alive():
            self._player = threading.Thread(target=self._play, name=f"play-{self.name}", daemon=True)
            self._player.start()

    def _play(self) -> None:
        try:
            while self.playing.is_set() and not self.closed.is_set():
                t0 = time.perf_counter()
                self.step(+1)
                self.closed.wait(max(0.0, 1.0 / PLAY_FPS - (time.perf_counter() - t0)))
        finally:
            self.playing.clear()
            self.gui_play.label, self.gui_play.icon = "Play", viser.Icon.PLAYER_PLAY
