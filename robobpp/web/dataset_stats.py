"""Box-size distributions and repeat rates of each dataset's public split, for the datasets page.

Computed on the server from the train split only (the test split is the private pool and never leaves the
workers). Box plots are drawn as SVG geometry here, so the page reads with no JavaScript at all.

- Sizes are what an episode sees: for ``diverse`` each SKU counts with its shipment proportion (the sampling
  weight), for ``repetitive`` each box of a record's pick quantity counts once.
- Repeat rate: the share of boxes in a sampled 80-box group that have the same size as the box before them
  (the paper's "repetitive" character); distinct sizes: how many different sizes one group holds.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np

log = logging.getLogger("robobpp.web")

DIMENSIONS = ("length", "width", "height")
SAMPLE_GROUPS = 30


@dataclass(frozen=True, slots=True)
class FiveNumbers:
    """Whiskers at the 5th and 95th percentiles, box at the quartiles (stated on the page)."""

    low: float
    q1: float
    median: float
    q3: float
    high: float
    minimum: float
    maximum: float


def weighted_quantiles(
    values: np.ndarray, quantiles: Sequence[float], weights: np.ndarray | None
) -> list[float]:
    """Quantiles of a weighted sample (inverse of the weighted empirical CDF)."""
    values = np.asarray(values, dtype=float)
    if weights is None:
        return [float(v) for v in np.quantile(values, quantiles)]
    order = np.argsort(values, kind="stable")
    v, w = values[order], np.asarray(weights, dtype=float)[order]
    cdf = np.cumsum(w) / w.sum()
    idx = np.minimum(np.searchsorted(cdf, np.asarray(quantiles), side="left"), len(v) - 1)
    return [float(v[i]) for i in idx]


def five_numbers(values: np.ndarray, weights: np.ndarray | None = None) -> FiveNumbers:
    low, q1, med, q3, high = weighted_quantiles(values, (0.05, 0.25, 0.5, 0.75, 0.95), weights)
    return FiveNumbers(low, q1, med, q3, high, float(np.min(values)), float(np.max(values)))


def repeat_stats(groups: Sequence[np.ndarray]) -> dict[str, float]:
    """Repeat rate and distinct sizes over sampled groups, each an (n, 3) array of box sizes in order."""
    repeats = 0
    pairs = 0
    distinct = []
    for dims in groups:
        if len(dims) == 0:
            continue
        same = np.all(dims[1:] == dims[:-1], axis=1)
        repeats += int(same.sum())
        pairs += len(dims) - 1
        distinct.append(len({tuple(row) for row in dims.tolist()}))
    return {
        "repeat_rate": repeats / pairs if pairs else 0.0,
        "distinct_per_group": float(np.mean(distinct)) if distinct else 0.0,
        "groups": float(len(distinct)),
    }


def summarise(dims: np.ndarray, weights: np.ndarray | None, groups: Sequence[np.ndarray]) -> dict[str, Any]:
    """Everything the page shows about one dataset's public split (plain dict, JSON-friendly)."""
    dims = np.asarray(dims, dtype=float)
    volume_l = dims.prod(axis=1) / 1000.0
    return {
        "entries": len(dims),
        "weighted": weights is not None,
        "dims": {name: five_numbers(dims[:, i], weights) for i, name in enumerate(DIMENSIONS)},
        "volume_l": five_numbers(volume_l, weights),
        **repeat_stats(groups),
    }


def _load(dataset: str) -> dict[str, Any]:
    from robobpp.datasets.pool import load_pool
    from robobpp.datasets.sampling import episode_specs

    pool = load_pool(dataset, "train")
    specs = episode_specs(dataset, split="train", groups=SAMPLE_GROUPS, seed=0)
    groups = [np.array([[b.length, b.width, b.height] for b in s.boxes]) for s in specs]
    out = summarise(pool.dims, pool.weights, groups)
    out["records"] = pool.records
    out["unplaceable"] = int(pool.notes.get("unplaceable", 0))
    return out


def data_available() -> bool:
    """Whether the converted data is in the cache (the page never starts a 42 MB download itself)."""
    try:
        from robobpp.datasets.cache import converted_dir, data_dir, read_manifest
    except ImportError:
        return False
    try:
        return read_manifest(converted_dir(data_dir())) is not None
    except Exception:  # noqa: BLE001 - a broken cache reads as "not available" on a web page
        return False


@lru_cache(maxsize=8)
def dataset_summary(dataset: str) -> dict[str, Any] | None:
    """The cached summary of one dataset, or None when its data is not fetched or cannot be read."""
    if not data_available():
        return None
    try:
        return _load(dataset)
    except Exception as exc:  # noqa: BLE001 - show the page without this dataset rather than a 500
        log.warning("datasets page: cannot summarise %s: %s", dataset, exc)
        return None


# ---- SVG box plots ---------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class BoxGlyph:
    label: str
    y: float
    low: float
    q1: float
    median: float
    q3: float
    high: float
    tooltip: str
    color: str


def nice_ticks(maximum: float, count: int = 5) -> list[float]:
    """Round tick values from 0 to at least ``maximum``."""
    if maximum <= 0:
        return [0.0, 1.0]
    raw = maximum / count
    magnitude = 10 ** np.floor(np.log10(raw))
    step = next(m * magnitude for m in (1, 2, 2.5, 5, 10) if m * magnitude >= raw)
    return [float(step * i) for i in range(int(np.ceil(maximum / step)) + 1)]


def boxplot_svg(rows: Sequence[tuple[str, FiveNumbers, str]], unit: str, width: int = 520) -> dict[str, Any]:
    """Geometry of a horizontal box plot (one row per label), rendered by the ``boxplot`` template macro."""
    left, right, row_h, top = 90.0, 20.0, 34.0, 10.0
    scale_max = max((r[1].high for r in rows), default=1.0)
    ticks = nice_ticks(scale_max)
    span = ticks[-1] or 1.0
    plot_w = width - left - right

    def x(v: float) -> float:
        return round(left + plot_w * v / span, 2)

    glyphs = [
        BoxGlyph(
            label,
            top + i * row_h + row_h / 2,
            x(f.low),
            x(f.q1),
            x(f.median),
            x(f.q3),
            x(f.high),
            f"{label}: median {f.median:g} {unit}, quartiles {f.q1:g}–{f.q3:g}, "
            f"5–95 % {f.low:g}–{f.high:g}, range {f.minimum:g}–{f.maximum:g}",
            color,
        )
        for i, (label, f, color) in enumerate(rows)
    ]
    height = top + len(rows) * row_h + 30
    return {
        "width": width,
        "height": height,
        "glyphs": glyphs,
        "ticks": [(x(t), f"{t:g}") for t in ticks],
        "axis_y": top + len(rows) * row_h,
        "left": left,
        "right": width - right,
        "top": top,
        "unit": unit,
        "half": row_h * 0.28,
    }
