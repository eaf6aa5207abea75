"""Reference data for validation (each file headed by its source: paper, figure, DOI)."""
from __future__ import annotations

from importlib import resources

import numpy as np


def load(name: str) -> tuple[np.ndarray, str]:
    """(columns as a float array, the '#' header text) of a shipped reference file."""
    text = resources.files(__name__).joinpath("data", name if name.endswith(".csv") else name + ".csv").read_text()
    header = "\n".join(line for line in text.splitlines() if line.startswith("#"))
    rows = [[float(x) for x in line.split(",")] for line in text.splitlines()
            if line.strip() and not line.startswith("#")]
    return np.array(rows), header


def surge_front(pos, kind, a: float) -> float:
    """Surge-front position Z/a: the largest x of the fluid (column of width a at x = 0)."""
    return float(pos[kind == 0, 0].max()) / a
