"""The fixed adjoint histogram dL/dH of the gradient comparisons (against mitransient's AD
and against the Dr.Jit reference): one definition, so both check the same loss."""
from __future__ import annotations

import numpy as np

SEED = 20261122


def adjoint_pattern(shape=(16, 16, 256), seed: int = SEED) -> np.ndarray:
    """dL/dH: 0.5 + six random plane-wave cosines in (y, x, t) (scaled to unit std), float32.
    Low frequencies (<= 1.5 cycles across the scan, 2-10 across the bins), so every scan
    point and time bin carries weight and a transposed, flipped or shifted layout changes L."""
    rng = np.random.default_rng(seed)
    sy, sx, nt = shape
    y, x, t = np.meshgrid(np.arange(sy), np.arange(sx), np.arange(nt), indexing="ij")
    f = np.zeros(shape)
    for _ in range(6):
        fy, fx = rng.uniform(-1.5, 1.5, 2)
        ft = rng.uniform(2, 10)
        ph = rng.uniform(0, 2 * np.pi)
        f += rng.normal() * np.cos(2 * np.pi * (fy * y / sy + fx * x / sx + ft * t / nt) + ph)
    return (0.5 + f / f.std()).astype(np.float32)
