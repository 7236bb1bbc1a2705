"""The paper protocol (robobpp.replay): Math Pack actions replayed open loop in a physical setting, ending as the
reference ends (collapse, infeasible action, the recorded episode's own ending)."""

from __future__ import annotations

from collections.abc import Sequence

import pytest

from robobpp.core import Action, EpisodeInfo, Observation
from robobpp.episode import EpisodeResult, run_episode
from robobpp.policies import load_policy
from robobpp.replay import (
    PAPER,
    check_loop,
    recorded_answers,
    replay_episode,
    replay_math_result,
    run_paper_loop,
)
from robobpp.vocabulary import LOOPS
from tests.conftest import make_spec


class Scripted:
    """A policy answering fixed actions, then raising (a policy failure after the script)."""

    name = "scripted"

    def __init__(self, actions: Sequence[Action | None]) -> None:
        self.actions = actions

    def reset(self, info: EpisodeInfo) -> None:
        return None

    def act(self, obs: Observation) -> Action | None:
        if obs.step >= len(self.actions):
            raise RuntimeError("script exhausted")
        return self.actions[obs.step]

    def close(self, reason: str) -> None:
        return None


def _answers(result: EpisodeResult) -> list[tuple[object, float]]:
    return [(s.action, s.decision_time) for s in result.steps]


def test_the_replay_plays_exactly_the_math_actions_and_times() -> None:
    # Identical flat boxes on the floor and in a second layer: nothing tips, every box is placed.
    spec = make_spec([(20, 20, 10)] * 12, container=(60, 40, 50), threshold=4.0)
    runs = run_paper_loop(spec, load_policy("dbl"), ["physics"])
    math, physics = runs["math"], runs["physics"]
    assert math.protocol == "closed" and math.setting == "math" and math.termination == "completed"
    assert physics.protocol == PAPER and physics.setting == "physics" and physics.policy == "dbl"
    assert physics.termination == "completed" and physics.boxes_placed == 12
    assert _answers(physics) == _answers(math)  # same x, y, orientation per step; decision times copied
    assert physics.metrics["decision_time"] == math.metrics["decision_time"]
    assert physics.to_dict()["protocol"] == PAPER


def test_a_collapse_ends_the_replay_at_that_box_and_counts_as_the_reference() -> None:
    # A heavy cube released on top of a thin pillar, far off its centre: both fall; the third action is never
    # used although it would be feasible.
    spec = make_spec([(8, 8, 40), (30, 30, 20), (10, 10, 10)], container=(80, 80, 100), threshold=4.0)
    actions = [Action(0, 0, 0), Action(0, 0, 0), Action(60, 60, 0)]
    result = replay_episode(spec, "physics", actions, [0.1, 0.2, 0.3], policy="scripted")
    assert result.termination == "collapse", result.termination_detail
    assert [s.step for s in result.steps] == [0, 1]
    assert result.steps[-1].collapsed and result.counters["placements_collapsed"] == 1
    assert result.protocol == PAPER
    # The reference's count: the collapse at box 1 leaves 1 box placed; box 1 is out of the utilisation, its
    # decision time and static stability out of the means; the pillar counts although it fell.
    assert result.boxes_placed == 1
    assert result.metrics["space_utilization"] == pytest.approx(8 * 8 * 40 / (80 * 80 * 100))
    assert result.metrics["decision_time"] == pytest.approx(0.1)
    assert result.metrics["static_stability"] == pytest.approx(result.steps[0].static_stability)
    assert len(result.final) == 2 and not any(f["in_place"] for f in result.final)  # the trace keeps both
    # The closed loop counts what is still in place at the end: both boxes placed, none in place.
    closed = run_episode(spec, Scripted(actions), "physics")
    assert (closed.termination, closed.boxes_placed, closed.metrics["space_utilization"]) == (
        "collapse",
        2,
        0.0,
    )


def test_the_replay_checks_the_height_on_the_planned_pile_not_on_the_physical_one() -> None:
    # A plank overhanging a block tips (its near end rises above the block's top); the third box, planned on
    # the block's top where the idealised pile has it end 3 cm under the lid, would stand above the container
    # on the tipped plank. The reference checks the height only on the idealised pile: the replay places it
    # (its weight rights the plank); the closed loop, which plans on the physical pile, refuses it.
    spec = make_spec([(20, 40, 10), (50, 40, 2), (20, 40, 10)], container=(60, 40, 25), threshold=50.0)
    actions = [Action(0, 0, 0)] * 3
    closed = run_episode(spec, Scripted(actions), "physics")
    assert closed.termination == "too_high" and closed.boxes_placed == 2, closed.termination_detail
    paper = replay_episode(spec, "physics", actions, [0.0] * 3)
    assert paper.termination == "completed" and paper.boxes_placed == 3, paper.termination_detail
    assert [s.termination for s in paper.steps] == [None, None, None]
    assert paper.metrics["space_utilization"] == pytest.approx((8000 + 4000 + 8000) / (60 * 40 * 25))


@pytest.mark.parametrize(
    ("actions", "ending", "steps"),
    [
        # the second box's footprint would stick out of the 40 cm container
        ([Action(0, 0, 0), Action(30, 0, 0), Action(0, 20, 0)], "out_of_bounds", 2),
        # the second box would stand on the first one, its top above the 45 cm container on the planned
        # (idealised) pile, where the reference checks it
        ([Action(0, 0, 0), Action(0, 0, 0), Action(0, 20, 0)], "too_high", 2),
    ],
)
def test_an_infeasible_replayed_action_ends_the_replay(
    actions: list[Action], ending: str, steps: int
) -> None:
    spec = make_spec([(20, 20, 25)] * 3, container=(40, 40, 45))
    result = replay_episode(spec, "physics", actions, [0.0] * 3)
    assert result.termination == ending, result.termination_detail
    assert len(result.steps) == steps and result.boxes_placed == 1


def test_an_early_math_ending_is_the_replay_ending() -> None:
    # Math finds no place for the third box (the container is full): the replay places two and ends alike.
    spec = make_spec([(20, 20, 15), (20, 20, 15), (20, 20, 15)], container=(40, 20, 20))
    runs = run_paper_loop(spec, load_policy("dbl"), ["physics"])
    math, physics = runs["math"], runs["physics"]
    assert math.termination == "no_feasible_placement" and math.boxes_placed == 2
    assert (physics.termination, physics.termination_detail) == (math.termination, math.termination_detail)
    assert physics.boxes_placed == 2 and _answers(physics) == _answers(math)


def test_a_math_policy_failure_and_a_refused_math_action_end_the_replay_alike() -> None:
    spec = make_spec([(20, 20, 15)] * 4, container=(40, 20, 20))
    failed = run_episode(spec, Scripted([Action(0, 0, 0)]), "math")  # raises on the second box
    assert failed.termination == "policy_error"
    replay = replay_math_result(failed, spec, "physics")
    assert (replay.termination, replay.termination_detail) == ("policy_error", failed.termination_detail)
    assert replay.boxes_placed == 1 and replay.policy == "scripted"
    # Math refuses the second box on top of the first (too high); the replay does not try it on its own pile.
    refused = run_episode(spec, Scripted([Action(0, 0, 0), Action(0, 0, 0)]), "math")
    assert refused.termination == "too_high" and recorded_answers(refused)[0] == [Action(0, 0, 0)]
    replay = replay_math_result(refused, spec, "physics")
    assert (replay.termination, replay.termination_detail) == ("too_high", refused.termination_detail)
    assert replay.boxes_placed == 1 and len(replay.steps) == 1


def test_bad_replays_are_refused_clearly() -> None:
    spec = make_spec([(10, 10, 10)] * 2, container=(20, 20, 20))
    math = run_episode(spec, load_policy("dbl"), "math")
    with pytest.raises(ValueError, match="not 'math'"):
        replay_math_result(math, spec, "math")
    physics = replay_math_result(math, spec, "physics")
    with pytest.raises(ValueError, match="replays a Math Pack episode"):
        replay_math_result(physics, spec, "physics")
    with pytest.raises(ValueError, match="decision times"):
        replay_episode(spec, "physics", [Action(0, 0, 0)], [])
    with pytest.raises(ValueError, match="completed episode answers every box"):
        replay_episode(spec, "physics", [Action(0, 0, 0)], [0.0])
    with pytest.raises(ValueError, match="per-step trace"):
        replay_math_result(EpisodeResult.from_dict(math.to_dict(trace=False)), spec, "physics")
    with pytest.raises(ValueError, match="unknown protocol 'open'"):
        check_loop("open")
    assert LOOPS == ("closed", "paper")


def test_results_without_a_protocol_load_as_closed() -> None:
    spec = make_spec([(10, 10, 10)] * 2, container=(20, 20, 20))
    data = run_episode(spec, load_policy("dbl"), "math").to_dict()
    assert data.pop("protocol") == "closed"  # as stored before protocols existed
    assert EpisodeResult.from_dict(data).protocol == "closed"


def test_the_replay_drives_the_execution_pack_too() -> None:
    spec = make_spec([(30, 30, 20)] * 4, container=(120, 100, 100), threshold=4.0)
    runs = run_paper_loop(spec, load_policy("dbl"), ["execution"])
    math, execution = runs["math"], runs["execution"]
    assert execution.protocol == PAPER and execution.setting == "execution"
    assert execution.termination == "completed" and _answers(execution) == _answers(math)
    trajectory_length = execution.metrics["trajectory_length"]
    assert execution.counters["operations"] == 4 and trajectory_length is not None and trajectory_length > 0
