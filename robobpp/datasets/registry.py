"""What robobpp knows about each dataset: container, collapse threshold, sampling rule, masses, splits."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from robobpp.core import ContainerSpec

Sampling = Literal["consecutive", "weighted", "uniform"]

#: Boxes per episode (BENCHMARK.md §2).
GROUP_SIZE = 80
#: Groups per dataset in the evaluation set.
EVAL_GROUPS = 30
SPLITS: tuple[str, ...] = ("train", "test")


@dataclass(frozen=True, slots=True)
class DatasetSpec:
    name: str
    title: str
    container: ContainerSpec
    collapse_threshold_cm: float
    sampling: Sampling
    #: Density (kg/m³) used when the source has no masses; None when it has them.
    density_kg_m3: float | None
    description: str


DATASETS: dict[str, DatasetSpec] = {
    "repetitive": DatasetSpec(
        "repetitive",
        "Repetitive",
        ContainerSpec(134, 125, 100),
        7.0,
        "consecutive",
        None,
        "Time-ordered pick records of an assembly-line warehouse; identical boxes arrive in runs.",
    ),
    "diverse": DatasetSpec(
        "diverse",
        "Diverse",
        ContainerSpec(120, 100, 170),
        4.0,
        "weighted",
        250.0,
        "6,801 logistics SKUs drawn in proportion to their shipments; widely varying sizes.",
    ),
    "longboard": DatasetSpec(
        "longboard",
        "Long Board",
        ContainerSpec(250, 120, 100),
        7.0,
        "uniform",
        400.0,
        "Flat furniture panels up to 2.5 m long; narrow feasible regions.",
    ),
}


class UnknownDatasetError(ValueError):
    pass


def get_dataset(name: str) -> DatasetSpec:
    try:
        return DATASETS[name]
    except KeyError:
        raise UnknownDatasetError(f"unknown dataset {name!r}; expected one of {', '.join(DATASETS)}") from None
