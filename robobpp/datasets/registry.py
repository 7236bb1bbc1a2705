"""What robobpp knows about each dataset: container, collapse threshold, sampling rule, masses, splits."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from robobpp.core import ContainerSpec

Sampling = Literal["consecutive", "palette", "weighted", "uniform"]

#: Boxes per episode (docs/benchmark.md, "Datasets").
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
    #: Data file inside the packsim wheel the records come from (docs/benchmark.md, "Datasets").
    source: str = ""
    #: How the public/private pools are split (the rule is documented in docs/datasets.md).
    split_rule: str = ""
    splits: tuple[str, ...] = ("train", "test")
    #: Rule of the ``test`` split when it differs from ``sampling``. The test pool ships in the public data,
    #: so a private group must not be a stretch of it that a policy could look up (docs/datasets.md,
    #: "Private groups nobody can look up"); ``sampling`` stays the paper's rule for the public split.
    test_sampling: Sampling | None = None

    def sampling_of(self, split: str) -> Sampling:
        """The rule groups of ``split`` are drawn with."""
        return self.test_sampling if split == "test" and self.test_sampling is not None else self.sampling


DATASETS: dict[str, DatasetSpec] = {
    "repetitive": DatasetSpec(
        "repetitive",
        "Repetitive",
        ContainerSpec(134, 125, 100),
        7.0,
        "consecutive",
        None,
        "Time-ordered pick records of an assembly-line warehouse; identical boxes arrive in runs.",
        "packsim/data/time_series/pg.xlsx (sheet E1_E2)",
        "test = the earliest 20 % of records (the authors' pg_test.xlsx), train = the rest (pg_train.xlsx)",
        test_sampling="palette",
    ),
    "diverse": DatasetSpec(
        "diverse",
        "Diverse",
        ContainerSpec(120, 100, 170),
        4.0,
        "weighted",
        250.0,
        "6,801 logistics SKUs drawn in proportion to their shipments; widely varying sizes.",
        "packsim/data/occupancy/deli.xlsx (sheet 道口物料清单)",
        "test = SKUs whose sha256('robobpp-diverse:' + code) mod 100 < 20, train = the rest",
    ),
    "longboard": DatasetSpec(
        "longboard",
        "Long Board",
        ContainerSpec(250, 120, 100),
        7.0,
        "uniform",
        400.0,
        "Flat furniture panels up to 2.5 m long; narrow feasible regions.",
        "packsim/data/flat_long/opai.txt",
        "the authors' opai_train.txt / opai_test.txt (a partition of opai.txt)",
    ),
}


class UnknownDatasetError(ValueError):
    pass


class UnknownSplitError(ValueError):
    pass


def check_split(dataset: str, split: str) -> DatasetSpec:
    """The dataset's spec, after checking that ``split`` is one of its splits (clear error otherwise)."""
    spec = get_dataset(dataset)
    if split not in spec.splits:
        raise UnknownSplitError(
            f"unknown split {split!r} of {dataset}; expected one of {', '.join(spec.splits)}"
        )
    return spec


def get_dataset(name: str) -> DatasetSpec:
    try:
        return DATASETS[name]
    except KeyError:
        raise UnknownDatasetError(
            f"unknown dataset {name!r}; expected one of {', '.join(DATASETS)}"
        ) from None
