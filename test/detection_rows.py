"""Detection rows for tests: each dict names the fields it sets, the rest keep ``perception.detections.empty``'s."""
from __future__ import annotations

import numpy as np

from dynenv_ros.perception.detections import empty


def rows(*entries: dict) -> np.ndarray:
    out = empty(len(entries))
    for row, values in zip(out, entries):
        for key, value in values.items():
            row[key] = value
    return out
