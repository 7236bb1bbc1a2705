"""Replay data: every Physics step records every box's actual pose, so a collapse is seen happening."""

from __future__ import annotations

import json
import math

import pytest

from robobpp.core import Action, Box
from robobpp.episode import Episode, EpisodeResult
from robobpp.sim.physics import PhysicsPack
from robobpp.web.trace import TraceError, viewer_payload
from tests.sim.physics._physics_specs import spec_of


def _toppled_post() -> EpisodeResult:
    """A heavy slab on a thin 50 cm post: the post (box 0) falls over and the slab with it."""
    post, slab = Box(8, 30, 50, 1.0), Box(30, 30, 10, 20.0)
    # The dataset masses (a 20 kg slab), not the reference's 0.5 kg for every box: the post then starts
    # to tip as soon as the slab lands.
    episode = Episode(spec_of([post, slab]), PhysicsPack(box_mass_kg=None))
    for action in (Action(60, 60, 0), Action(53, 60, 0)):
        episode.step(action, 0.0)
    result = episode.result("scripted")
    episode.setting.close()
    return result


def test_each_step_records_every_box_pose_compactly() -> None:
    result = _toppled_post()
    assert result.termination == "collapse"
    first, second = (s.extra["poses"] for s in result.steps)
    assert len(first) == 1 and len(second) == 2  # item i is box i, every box placed so far
    for pose in (*first, *second):
        assert len(pose) == 7 and all(type(v) is float for v in pose)  # plain floats, not numpy
        assert all(round(v, 2) == v for v in pose[:3]) and all(round(v, 5) == v for v in pose[3:])
        assert math.isclose(math.hypot(*pose[3:]), 1.0, abs_tol=1e-4)
    # Box 0 stood upright at its target after step 0 and lies on its side 30 cm away after the collapse
    # (on the deck or on the slab: its centre is no longer 25 cm up, its attitude turned by about 90°).
    assert math.dist(first[0][:2], (64.0, 75.0)) < 0.1 and abs(first[0][2] - 25.0) < 0.1
    assert math.dist(second[0][:2], first[0][:2]) > 20 and second[0][2] < 15 and abs(second[0][6]) < 0.9
    assert 0 in result.steps[1].extra["collapsed_boxes"]
    # The new box's pose is its reported placement's centre.
    placed = result.steps[1].placement
    assert placed is not None
    centre = (
        placed["x"] + placed["length"] / 2,
        placed["y"] + placed["width"] / 2,
        placed["z"] + placed["height"] / 2,
    )
    assert math.dist(second[1][:3], centre) < 0.01


def test_the_replay_reader_expands_compact_poses() -> None:
    data = json.loads(json.dumps(_toppled_post().to_dict()))  # the trace is JSON as it is
    payload = viewer_payload(data)
    poses = payload["steps"][1]["poses"]
    assert [p["index"] for p in poses] == [0, 1]
    post = poses[0]
    assert (post["length"], post["width"], post["height"]) == (8, 30, 50)
    raw = data["steps"][1]["extra"]["poses"][0]
    assert math.isclose(post["x"] + 4, raw[0]) and math.isclose(post["z"] + 25, raw[2])
    assert len(post["quaternion"]) == 4


def test_a_compact_pose_of_a_box_not_yet_placed_is_refused() -> None:
    data = json.loads(json.dumps(_toppled_post().to_dict()))
    data["steps"][0]["extra"]["poses"].append([1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 1.0])  # box 1 comes later
    with pytest.raises(TraceError, match="box 1 was not placed"):
        viewer_payload(data)
    data = json.loads(json.dumps(_toppled_post().to_dict()))
    data["steps"][1]["extra"]["poses"][0] = [1.0, 2.0, 3.0]
    with pytest.raises(TraceError, match="qx, qy, qz, qw"):
        viewer_payload(data)


def test_a_collapse_is_recorded_over_time() -> None:
    """Step 1's track shows the post falling: sampled from the release on, ending where the step ends."""
    result = _toppled_post()
    track = result.steps[1].extra["track"]
    times = track["t"]
    assert track["tick_s"] == 1 / 240
    assert times[0] == 0 and times == sorted(times) and times[-1] > 60  # a fall takes a while
    assert all(b - a <= 8 for a, b in zip(times, times[1:], strict=False))  # 30 samples per second
    rows = {row[0]: row for row in track["boxes"]}
    assert set(rows) == {0, 1}
    before, after = result.steps[0].extra["poses"][0], result.steps[1].extra["poses"][0]
    post = rows[0]
    first, samples = post[1], [post[2 + 7 * k : 9 + 7 * k] for k in range((len(post) - 2) // 7)]
    # Kept from just before it starts to move until it lies still: mm and 10⁻⁴, the first sample the post
    # standing as step 0 left it, the last where it lies now.
    assert 0 <= first < 4 and first + len(samples) <= len(times) and len(samples) > 8
    assert math.dist([v / 10 for v in samples[0][:3]], before[:3]) < 0.1
    assert math.dist([v / 10 for v in samples[-1][:3]], after[:3]) < 0.1
    heights = [s[2] for s in samples]
    assert heights[0] > 240 and heights[-1] < 150  # upright 25 cm, then on its side (<= 14 cm)


def test_recording_changes_nothing_and_quiet_steps_record_nothing() -> None:
    def run(record: bool) -> EpisodeResult:
        pack = PhysicsPack()
        pack.record_tracks = record
        boxes = [Box(30, 30, 20, 5.0), Box(30, 30, 20, 5.0), Box(8, 30, 50, 1.0), Box(30, 30, 10, 20.0)]
        episode = Episode(spec_of(boxes), pack)
        for action in (Action(0, 0, 0), Action(30, 0, 0), Action(60, 60, 0), Action(53, 60, 0)):
            episode.step(action, 0.0)
        result = episode.result("scripted")
        pack.close()
        return result

    on, off = run(True), run(False)
    assert [s.extra["poses"] for s in on.steps] == [s.extra["poses"] for s in off.steps]
    assert not any("track" in s.extra for s in off.steps)
    # A box released 2 mm above a flat floor drops 2 mm, too little to see: no track.
    assert "track" not in on.steps[0].extra and "track" not in on.steps[1].extra
    assert on.steps[3].collapsed and 0 < len(on.steps[3].extra["track"]["boxes"]) <= 4


def test_the_replay_reader_checks_tracks() -> None:
    data = json.loads(json.dumps(_toppled_post().to_dict()))
    payload = viewer_payload(data)
    track = data["steps"][1]["extra"]["track"]
    assert payload["steps"][1]["track"]["boxes"] == track["boxes"]
    assert payload["steps"][1]["track"]["t"] == [round(t / 0.24, 3) for t in track["t"]]  # ms
    bad = json.loads(json.dumps(data))
    bad["steps"][0]["extra"]["track"] = track  # step 0 cannot move box 1, placed at step 1
    with pytest.raises(TraceError, match="moves a box placed later"):
        viewer_payload(bad)
    bad = json.loads(json.dumps(data))
    bad["steps"][1]["extra"]["track"]["boxes"][0].pop()  # not 7 numbers per sample
    with pytest.raises(TraceError, match="7 integers per sample"):
        viewer_payload(bad)
    bad = json.loads(json.dumps(data))
    bad["steps"][1]["extra"]["track"]["t"][1] = -3
    with pytest.raises(TraceError, match="in order"):
        viewer_payload(bad)
