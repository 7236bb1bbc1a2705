"""Synthetic episode sets: same interface as the real data, and invalid sizes refused at load."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from robobpp.core import ContainerSpec
from robobpp.datasets import SpecFileError
from robobpp.datasets.synthetic import load_specs, save_specs, synthetic_episode_specs


def test_deterministic_per_group_and_within_ranges() -> None:
    a = synthetic_episode_specs(3, seed=4, length_range=(20, 30), width_range=(10, 12), height_range=(5, 6))
    assert a == synthetic_episode_specs(
        3, seed=4, length_range=(20, 30), width_range=(10, 12), height_range=(5, 6)
    )
    assert (
        synthetic_episode_specs(5, seed=4, length_range=(20, 30), width_range=(10, 12), height_range=(5, 6))[
            :3
        ]
        == a
    )
    assert a != synthetic_episode_specs(
        3, seed=5, length_range=(20, 30), width_range=(10, 12), height_range=(5, 6)
    )
    for spec in a:
        assert len(spec.boxes) == 80 and spec.container == ContainerSpec(134, 125, 100)
        for b in spec.boxes:
            assert 20 <= b.length <= 30 and 10 <= b.width <= 12 and 5 <= b.height <= 6
            assert b.length == int(b.length)  # 1 cm resolution by default
            assert b.mass == pytest.approx(b.volume * 1e-6 * 250)


def test_dataset_container_and_profiles() -> None:
    (spec,) = synthetic_episode_specs(
        1, container="longboard", profile="tiny", resolution=None, group_size=10
    )
    assert spec.container == ContainerSpec(250, 120, 100) and spec.collapse_threshold_cm == 7.0
    assert all(0.5 <= b.length <= 2 for b in spec.boxes) and len(spec.boxes) == 10
    (huge,) = synthetic_episode_specs(1, profile="huge", container=ContainerSpec(100, 100, 100))
    assert all(b.length > 100 for b in huge.boxes)  # valid boxes that fit no container


@pytest.mark.parametrize(
    "kwargs",
    [
        {"length_range": (0, 10)},
        {"width_range": (-5, 10)},
        {"height_range": (5, math.nan)},
        {"length_range": (10, 5)},
        {"profile": "gigantic"},
        {"density_kg_m3": 0.0},
        {"resolution": -1.0},
        {"container": "nope"},
    ],
)
def test_generator_refuses_bad_parameters(kwargs: dict) -> None:
    with pytest.raises(ValueError):
        synthetic_episode_specs(1, **kwargs)


def test_json_round_trip(tmp_path: Path) -> None:
    specs = synthetic_episode_specs(2, seed=9, container="diverse", resolution=0.5)
    path = tmp_path / "set.json"
    save_specs(path, specs)
    assert load_specs(path) == specs


def _doc(boxes: list) -> dict:
    return {
        "format": "robobpp-episodes/1",
        "dataset": "synthetic",
        "split": "train",
        "container": {"length": 100, "width": 100, "height": 100},
        "collapse_threshold_cm": 7,
        "groups": [{"group": 0, "seed": 1, "boxes": boxes}],
    }


@pytest.mark.parametrize(
    ("box", "field", "shown"),
    [
        ([0, 10, 10], "length", "0"),
        ([10, -3, 10], "width", "-3"),
        ([10, 10, float("nan")], "height", "nan"),
        ([10, 10, float("inf")], "height", "inf"),
        ([10, 10, 10, 0], "mass", "0"),
        ([10, "10", 10], "width", "'10'"),
        ([10, True, 10], "width", "True"),
    ],
)
def test_json_refuses_invalid_sizes_naming_the_box(tmp_path: Path, box: list, field: str, shown: str) -> None:
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(_doc([[1, 1, 1], box])))  # NaN/Infinity are written as JSON literals
    with pytest.raises(SpecFileError) as err:
        load_specs(path)
    message = str(err.value)
    assert str(path) in message and "group 0 box 1" in message and field in message and shown in message


@pytest.mark.parametrize(
    "mutate",
    [
        lambda d: d.pop("container"),
        lambda d: d["container"].update(length=0),
        lambda d: d.update(collapse_threshold_cm=-1),
        lambda d: d.update(groups=[]),
        lambda d: d.update(format="other/9"),
        lambda d: d["groups"][0].update(boxes=[[1, 2]]),
        lambda d: d["groups"][0].update(seed=-1),
    ],
)
def test_json_refuses_malformed_documents(tmp_path: Path, mutate) -> None:
    doc = _doc([[10, 10, 10]])
    mutate(doc)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(SpecFileError, match="bad.json"):
        load_specs(path)


def test_unreadable_files(tmp_path: Path) -> None:
    with pytest.raises(SpecFileError, match="cannot read"):
        load_specs(tmp_path / "absent.json")
    (tmp_path / "x.json").write_text("{")
    with pytest.raises(SpecFileError, match="invalid JSON"):
        load_specs(tmp_path / "x.json")
    (tmp_path / "x.yaml").write_text("")
    with pytest.raises(SpecFileError, match="unknown episode-set format"):
        load_specs(tmp_path / "x.yaml")


def test_csv_load_and_refusals(tmp_path: Path) -> None:
    path = tmp_path / "boxes.csv"
    path.write_text("group,length,width,height,mass\n0,10,20,30,1.5\n0,5,5,5,\n1,7,8,9,2\n")
    specs = load_specs(path, container="repetitive")
    assert [len(s.boxes) for s in specs] == [2, 1]
    assert specs[0].boxes[1].mass == 1.0 and specs[0].container == ContainerSpec(134, 125, 100)
    with pytest.raises(SpecFileError, match="needs container"):
        load_specs(path)
    for bad, hint in [
        ("0,10,0,30,1", "width"),
        ("0,10,20,-1,1", "height"),
        ("0,nan,1,1,1", "length"),
        ("0,inf,1,1,1", "length"),
        ("x,1,1,1,1", "group"),
        ("-1,1,1,1,1", "group"),
    ]:
        path.write_text(f"group,length,width,height,mass\n{bad}\n")
        with pytest.raises(SpecFileError, match=hint) as err:
            load_specs(path, container=ContainerSpec(10, 10, 10))
        assert "boxes.csv line 2" in str(err.value)
