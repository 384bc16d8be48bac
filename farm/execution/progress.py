"""The progress line of a farm run: tqdm when installed, else one plain line per scene."""

from __future__ import annotations

import sys
import time


class _PlainProgress:
    """Stand-in for tqdm when it is not installed: one line per finished scene, with ETA."""

    def __init__(self, total: int, file, **_):
        self.total, self.n, self.file, self.t0, self.postfix = total, 0, file, time.monotonic(), {}

    def update(self, n: int = 1) -> None:
        self.n += n
        elapsed = time.monotonic() - self.t0
        eta = elapsed / self.n * (self.total - self.n)
        extra = " ".join(f"{k}={v}" for k, v in self.postfix.items())
        print(f"farm: {self.n}/{self.total} scenes, {elapsed:.0f} s, ETA {eta:.0f} s {extra}".rstrip(),
              file=self.file, flush=True)

    def set_postfix(self, refresh: bool = False, **values) -> None:
        self.postfix = values

    def close(self) -> None:
        pass



def progress_bar(total: int):
    """A tqdm bar on stderr, or _PlainProgress where tqdm is missing (real Blender's Python)."""
    try:
        from tqdm import tqdm
    except ImportError:  # e.g. real Blender's bundled Python without tqdm
        tqdm = _PlainProgress
    return tqdm(total=total, unit="scene", file=sys.stderr, dynamic_ncols=True, desc="farm", smoothing=0.1)
