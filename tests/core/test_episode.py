"""The episode loop: termination reasons, trace, metrics, and hostile policies."""

import math
from typing import Any

import numpy as np
import pytest

from robobpp.core import Action
from robobpp.episode import Episode, EpisodeResult, StepRecord, run_episode
from robobpp.policies import BasePolicy, PolicyError, PolicyLoadError, load_policy
from tests.conftest import make_spec


def _placement(step: StepRecord) -> dict[str, Any]:
    """Where the step placed its box (it placed one)."""
    assert step.placement is not None, step
    return step.placement


class Scripted(BasePolicy):
    """Answers from a fixed list (anything, including garbage)."""

    name = "scripted"

    def __init__(self, answers):
        self.answers = list(answers)
        self.closed_with = None

    def act(self, obs):
        answer = self.answers.pop(0)
        if isinstance(answer, Exception):
            raise answer
        return answer

    def close(self, reason):
        self.closed_with = reason


def test_math_episode_stacks_and_measures():
    spec = make_spec([(10, 10, 2), (5, 10, 3), (5, 10, 3)])
    policy = Scripted([Action(0, 0, 0), Action(0, 0, 0), Action(5, 0, 0)])
    result = run_episode(spec, policy, "math")
    assert result.termination == "completed" and result.boxes_placed == 3
    assert [_placement(s)["z"] for s in result.steps] == [0, 2, 2]
    assert result.metrics["space_utilization"] == pytest.approx(500 / 1000)
    assert result.metrics["occupancy"] == pytest.approx(1.0)
    decision_time = result.metrics["decision_time"]
    assert decision_time is not None and decision_time >= 0
    assert policy.closed_with == "completed"


@pytest.mark.parametrize(
    ("answer", "reason"),
    [
        (Action(math.nan, 0, 0), "invalid_action"),
        (Action(0, math.inf, 0), "invalid_action"),
        (Action(0, 0, 7), "invalid_action"),
        (Action(8, 0, 0), "out_of_bounds"),
        (Action(-3, 0, 0), "out_of_bounds"),
        (Action(1e300, 0, 0), "out_of_bounds"),
        (None, "no_feasible_placement"),
        ("not an action", "policy_error"),
        (RuntimeError("boom"), "policy_error"),
        (PolicyError("policy_timeout", "no answer within 1 s"), "policy_timeout"),
    ],
)
def test_bad_answers_end_the_episode_with_a_reason(answer, reason):
    spec = make_spec([(5, 5, 5), (5, 5, 5)])
    policy = Scripted([Action(0, 0, 0), answer])
    result = run_episode(spec, policy, "math")
    assert result.termination == reason
    assert result.termination_detail
    assert result.boxes_placed == 1  # the first box stays counted
    assert policy.closed_with == reason


def test_box_above_container_top_is_refused():
    spec = make_spec([(10, 10, 6), (10, 10, 6)])
    result = run_episode(spec, Scripted([Action(0, 0, 0), Action(0, 0, 0)]), "math")
    assert result.termination == "too_high" and result.boxes_placed == 1


def test_dbl_fills_hand_built_scene_bottom_left_first():
    spec = make_spec([(5, 5, 5)] * 8)
    result = run_episode(spec, load_policy("dbl"), "math")
    corners = [(_placement(s)["x"], _placement(s)["y"], _placement(s)["z"]) for s in result.steps]
    assert corners[:4] == [(0, 0, 0), (0, 5, 0), (5, 0, 0), (5, 5, 0)]
    assert all(z == 5 for _, _, z in corners[4:])
    assert result.metrics["space_utilization"] == pytest.approx(1.0)


def test_random_policy_is_seeded_per_episode(random_spec):
    a = run_episode(random_spec, load_policy("random"), "math")
    b = run_episode(random_spec, load_policy("random"), "math")
    assert [s.action for s in a.steps] == [s.action for s in b.steps]


def test_result_round_trips_through_dict(random_spec):
    result = run_episode(random_spec, load_policy("dbl"), "math")
    again = EpisodeResult.from_dict(result.to_dict())
    assert again == result
    assert "steps" not in result.to_dict(trace=False)


def test_observation_is_the_state_and_read_only():
    episode = Episode(make_spec([(5, 5, 5), (5, 5, 5)]), "math", lookahead=1)
    obs = episode.observe()
    assert obs.lookahead == (episode.spec.boxes[1],)
    with pytest.raises(ValueError):
        obs.heightmap[0, 0] = 3
    episode.step(Action(0, 0, 0), 0.0)
    assert episode.observe().heightmap[0, 0] == 5 and len(episode.observe().placed) == 1


def test_an_observation_does_not_change_after_it_is_returned():
    """A policy may keep an observation (a history, a replay buffer): later steps must not rewrite it, and
    re-enabling writes on it must not reach the simulator's state."""
    episode = Episode(make_spec([(5, 5, 5)] * 4, (10, 10, 20)), "math")
    kept = episode.observe()
    before = kept.heightmap.copy()
    for x in (0, 5, 0):
        episode.step(Action(x, 0, 0), 0.0)
    np.testing.assert_array_equal(kept.heightmap, before)
    assert kept.placed == () and not kept.heightmap.flags.writeable
    later = episode.observe()
    later.heightmap.flags.writeable = True  # a policy that insists writes to its own copy only
    later.heightmap[:] = 99
    assert episode.observe().heightmap[0, 0] == 10 and episode.setting.state().heightmap.max() == 10


def test_load_policy_errors_are_clear():
    with pytest.raises(PolicyLoadError, match="unknown policy"):
        load_policy("nope")
    with pytest.raises(PolicyLoadError, match="cannot import"):
        load_policy("no_such_module_xyz:Thing")
    with pytest.raises(PolicyLoadError, match="no attribute"):
        load_policy("robobpp.policies.dbl:Missing")


def test_user_policy_from_module_path_without_hooks(tmp_path, monkeypatch):
    (tmp_path / "mypolicy.py").write_text(
        "from robobpp.core import Action\nclass Corner:\n    def act(self, obs):\n        return Action(0, 0, 0)\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    policy = load_policy("mypolicy:Corner")
    result = run_episode(make_spec([(5, 5, 5), (5, 5, 5)]), policy, "math")
    assert result.boxes_placed == 2 and _placement(result.steps[1])["z"] == 5
