"""The paper loop's plan and dispatch (robobpp/replay.py), in Math Pack only: what a Math episode hands its
replays comes back as the same answers, and play() keeps the order of the settings asked for."""

from __future__ import annotations

import json

from robobpp.episode import EpisodeResult, run_episode
from robobpp.policies import load_policy
from robobpp.replay import math_result_of, paper_settings, plan_of, play, recorded_answers
from robobpp.vocabulary import CLOSED, PAPER
from tests.conftest import make_spec


def test_a_plan_gives_back_the_math_episodes_answers() -> None:
    spec = make_spec([(20, 20, 10)] * 12, container=(60, 40, 50), threshold=4.0)
    math = run_episode(spec, load_policy("dbl"), "math")
    plan = json.loads(json.dumps(plan_of(math.to_dict())))  # as stored: JSON
    back = math_result_of(plan, spec)
    assert recorded_answers(back) == recorded_answers(math)
    assert (back.termination, back.boxes_placed, back.policy) == (
        math.termination,
        math.boxes_placed,
        math.policy,
    )


def test_which_runs_get_the_paper_loop() -> None:
    assert paper_settings(["math", "physics", "execution"], "private") == ["physics", "execution"]
    assert paper_settings(["math", "execution"], "public") == ["execution"]
    assert paper_settings(["physics"], "private") == []  # no Math Pack: no plan
    assert paper_settings(["math", "physics"], "verify") == []  # verified on closed loop only


def test_play_in_math_pack_is_one_episode_under_either_loop() -> None:
    spec = make_spec([(20, 20, 10)] * 6, container=(60, 40, 50), threshold=4.0)
    closed = play(CLOSED, spec, load_policy("dbl"), ["math"])
    paper = play(PAPER, spec, load_policy("dbl"), ["math"])
    assert [r.setting for r in closed] == [r.setting for r in paper] == ["math"]

    def placements(result: EpisodeResult) -> list[tuple[float, float, int] | None]:
        return [None if a is None else (a.x, a.y, a.orientation) for a in recorded_answers(result)[0]]

    assert placements(closed[0]) == placements(paper[0])  # the same episode (its timings vary)
