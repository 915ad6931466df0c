"""The CPU thread split of a batched call (Warp releases the GIL while a CPU kernel runs)."""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np


def split(B: int, device, threads: int | None) -> list[tuple[int, int]]:
    """Rod ranges, one per CPU thread (one range on CUDA or for small batches)."""
    n = 1 if device.is_cuda else (threads or os.cpu_count() or 1)
    n = max(1, min(n, B // 32 if B >= 64 else 1))
    bounds = np.linspace(0, B, n + 1).astype(int)
    return [(int(lo), int(hi)) for lo, hi in zip(bounds[:-1], bounds[1:])]


def parallel(fn, items: list):
    """Run fn over items, on threads when there is more than one."""
    if len(items) == 1:
        return [fn(items[0])]
    with ThreadPoolExecutor(len(items)) as pool:
        return list(pool.map(fn, items))
