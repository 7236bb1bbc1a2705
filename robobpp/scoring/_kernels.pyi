"""Types of the compiled steps of a board's full computation (robobpp/scoring/_kernels.c): arrays C-contiguous."""

import numpy as np

def rank_rows(scores: np.ndarray, out: np.ndarray, rows: int, n: int, /) -> bool: ...
def order_statistics(values: np.ndarray, n: int, positions: np.ndarray, out: np.ndarray, /) -> bool: ...
def add_timing_noise(
    times: np.ndarray,
    seeds: np.ndarray,
    rows: np.ndarray,
    share: float,
    resolution: float,
    golden: int,
    mix1: int,
    mix2: int,
    /,
) -> None: ...
def fold_min_max(values: np.ndarray, low: np.ndarray, high: np.ndarray, /) -> None: ...
def add_weighted_min_max(
    values: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    total: np.ndarray,
    weight: float,
    floor: float,
    least: float,
    resolved: bool,
    up: bool,
    finish: bool,
    /,
) -> None: ...
