"""Sample images for the GUI: the service's PNG (channels side by side in grey) as an RGB array."""

from __future__ import annotations

import cv2
import numpy as np

MIN_HEIGHT = 96  # small canvases are scaled up (nearest) so the GUI does not blur them


def sample_image(png: bytes) -> np.ndarray:
    """PNG bytes -> (H, W, 3) uint8 RGB; a blank (8, 32, 3) image when the PNG does not decode."""
    grey = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_GRAYSCALE)
    if grey is None or grey.size == 0:
        return np.zeros((8, 32, 3), np.uint8)
    if grey.shape[0] < MIN_HEIGHT:
        k = int(np.ceil(MIN_HEIGHT / grey.shape[0]))
        grey = cv2.resize(grey, (grey.shape[1] * k, grey.shape[0] * k), interpolation=cv2.INTER_NEAREST)
    return np.repeat(grey[:, :, None], 3, axis=2)


def blank_image() -> np.ndarray:
    """The placeholder shown before a sample is loaded, or for a segment without a sample."""
    return np.full((48, 192, 3), 24, np.uint8)
