"""Augmentation of (B, C, S, S) canvas batches: flips and shifts, intensity variation, erased rectangles."""

from __future__ import annotations

import torch
import torch.nn.functional as F


def augment_batch(x: torch.Tensor, max_shift: int, generator: torch.Generator, erase: float = 0.0) -> torch.Tensor:
    """Random horizontal flip and integer shifts (zero fill) of each canvas in (B, C, S, S); with
    `erase` > 0, that share of the canvases also loses one random rectangle (`erase_rectangles`)."""
    b, _, s, _ = x.shape
    dev = x.device
    flip = torch.rand(b, generator=generator) < 0.5
    x = torch.where(flip.to(dev)[:, None, None, None], x.flip(3), x)
    if erase > 0:
        x = erase_rectangles(x, erase, generator)
    if max_shift <= 0:
        return x
    shifts = torch.randint(-max_shift, max_shift + 1, (2, b), generator=generator).to(dev)  # (2, B)
    padded = F.pad(x, (max_shift,) * 4)  # (B, C, S + 2 pad, S + 2 pad)
    base = torch.arange(s, device=dev) + max_shift  # (S,)
    rows = base[None, :] - shifts[0][:, None]  # (B, S)
    cols = base[None, :] - shifts[1][:, None]  # (B, S)
    bi = torch.arange(b, device=dev)[:, None, None]  # (B, 1, 1)
    out = padded.permute(0, 2, 3, 1)[bi, rows[:, :, None], cols[:, None, :]]  # (B, S, S, C)
    return out.permute(0, 3, 1, 2)  # (B, C, S, S), stored NHWC: the network's channels_last, no copy


def vary_intensity(x: torch.Tensor, drop: float, gamma: float, generator: torch.Generator) -> torch.Tensor:
    """(B, C, S, S) float canvases in [0, 1] with the intensity channel (2) emptied in a `drop`
    share of them (a sensor without intensity: the geometry-only input) and raised to a random
    power 2^u, u uniform in [-gamma, gamma], in the others (another sensor's response to
    reflectivity)."""
    b = x.shape[0]
    keep = (torch.rand(b, generator=generator) >= drop).to(x.dtype)  # (B,)
    power = torch.pow(2.0, (torch.rand(b, generator=generator) * 2.0 - 1.0) * gamma)  # (B,)
    intensity = x[:, 2].clamp_min(0.0).pow(power.to(x.device)[:, None, None]) * keep.to(x.device)[:, None, None]
    return torch.cat([x[:, :2], intensity[:, None], x[:, 3:]], dim=1)


def erase_rectangles(x: torch.Tensor, share: float, generator: torch.Generator) -> torch.Tensor:
    """(B, C, S, S) with `share` of the canvases zeroed inside one random rectangle each, its
    sides a tenth to half of the canvas side (random erasing)."""
    b, _, s, _ = x.shape
    hit = torch.rand(b, generator=generator) < share  # (B,)
    size = (torch.rand(2, b, generator=generator) * 0.4 + 0.1) * s  # (2, B) rectangle height, width
    start = torch.rand(2, b, generator=generator) * (s - size)  # (2, B) top, left
    idx = torch.arange(s, dtype=torch.float32)  # (S,)
    inside = [(idx[None, :] >= start[k][:, None]) & (idx[None, :] < (start[k] + size[k])[:, None]) for k in (0, 1)]
    mask = inside[0][:, :, None] & inside[1][:, None, :] & hit[:, None, None]  # (B, S, S)
    return x.masked_fill(mask.to(x.device)[:, None], 0.0)
