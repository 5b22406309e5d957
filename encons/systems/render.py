"""Grey-scale frames of planar rod chains, drawn by torch ops over a pixel grid (no drawing library).

The picture is Gym's pendulum (Brockman et al. 2016), as Greydanus et al. (2019) and Lim & Kasim
(2023, §6) observe it: each rod a capsule of width 0.2 (Gym's ``make_capsule(1, .2)`` for a rod of
length 1) from the pivot or the previous bob, bright (1) on a dark (0) background, the frame centred
on the pivot. Greydanus et al. took Gym's RGB render, cropped it, kept red minus green (the rod) and
resized it to 28 × 28; here the rod is drawn at the frame's size directly, anti-aliased by a one-pixel
linear ramp at its edge, so the frames are deterministic and identical on every machine.
"""

from __future__ import annotations

import torch
from torch import Tensor

ROD_WIDTH = 0.2  # Gym's capsule width for a rod of length 1, in units of the rod length
MARGIN = 1.2  # the frame spans ±MARGIN × the chain's total length around the pivot


def pixel_centres(size: int, extent: float, like: Tensor) -> Tensor:
    """World coordinates (size, size, 2) of the pixel centres of a frame spanning [−extent, extent]²;
    row 0 is the top (y = +extent side), column 0 the left (x = −extent)."""
    step = 2 * extent / size
    c = -extent + step * (torch.arange(size, dtype=like.dtype, device=like.device) + 0.5)
    y, x = torch.meshgrid(c.flip(0), c, indexing="ij")
    return torch.stack([x, y], -1)


def to_pixels(points: Tensor, size: int, extent: float) -> Tensor:
    """(column, row) pixel coordinates of world points (..., 2), pixel centres at integers."""
    scale = size / (2 * extent)
    return torch.stack([(points[..., 0] + extent) * scale - 0.5, (extent - points[..., 1]) * scale - 0.5], -1)


def render_rods(points: Tensor, lengths: Tensor, size: int) -> Tensor:
    """Frames (..., size, size) in [0, 1] of the chain pivot → points[..., 0, :] → points[..., 1, :] …

    ``points`` (..., K, 2) are the bob positions (y up, pivot at the origin), ``lengths`` (K,) the rod
    lengths; the frame spans ±``MARGIN`` × Σ lengths. Every frame and pixel in one batched expression:
    memory grows as (frames × K × size²).
    """
    extent = MARGIN * float(lengths.sum())
    grid = pixel_centres(size, extent, points).reshape(-1, 2)  # (P, 2)
    start = torch.cat([torch.zeros_like(points[..., :1, :]), points[..., :-1, :]], -2)  # (..., K, 2)
    seg = points - start
    rel = grid[:, None, :] - start[..., None, :, :]  # (..., P, K, 2)
    along = ((rel * seg[..., None, :, :]).sum(-1) / (seg**2).sum(-1)[..., None, :]).clamp(0, 1)
    dist = (rel - along[..., None] * seg[..., None, :, :]).norm(dim=-1)  # (..., P, K)
    half = 0.5 * ROD_WIDTH * lengths.to(points)
    pixel = 2 * extent / size
    ink = ((half - dist) / pixel + 0.5).clamp(0, 1).amax(-1)  # one-pixel edge ramp
    return ink.unflatten(-1, (size, size))
