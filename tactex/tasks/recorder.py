"""Time series of a run: append one row of named values per tick, save as a plain ``.npz``."""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import numpy as np

__all__ = ["Recorder"]


class Recorder:
    """Collects named series (scalars or fixed-size vectors) row by row.

    ``every`` keeps one row in ``every`` calls (e.g. 10 → 100 Hz from a 1 kHz loop).
    """

    def __init__(self, every: int = 1) -> None:
        self.every = max(int(every), 1)
        self._count = 0
        self._data: dict[str, list] = defaultdict(list)

    def due(self) -> bool:
        """True when the next :meth:`add` will be kept; call before building an expensive row."""
        return self._count % self.every == 0

    def add(self, **values: object) -> None:
        keep = self._count % self.every == 0
        self._count += 1
        if keep:
            for key, value in values.items():
                self._data[key].append(np.asarray(value, dtype=float))

    def __len__(self) -> int:
        return len(next(iter(self._data.values()), []))

    def arrays(self) -> dict[str, np.ndarray]:
        """All series as arrays (rows × …); series of unequal length are kept as recorded."""
        return {k: np.stack(v) if v else np.zeros(0) for k, v in self._data.items()}

    def save(self, path: str | Path) -> Path:
        out = Path(path)
        out.parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(out, **self.arrays())
        return out
