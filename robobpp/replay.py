"""The paper's loop: plan every action in Math Pack, then replay the action list open loop in a physical setting.

This is how the paper's Physics and Execution tables were made (the reference simulator is a replayer: it reads
the actions an algorithm computed offline on idealised geometry and executes them; physics never feeds back).
robobpp's own loop, ``closed``, lets the policy observe the physical state at every step instead
(docs/benchmark.md, "Two protocols"; the two are :data:`robobpp.vocabulary.Loop`).

Closed and paper part in one place: :func:`play` runs a group's episodes under either loop. So does the
server's: which runs of a submission are replayed (:func:`paper_settings`) and the plan a Math Pack episode
hands its replays, written (:func:`plan_of`) and read back (:func:`math_result_of`), are decided here, for
the database (robobpp.db.work) and the workers (robobpp.worker.run) alike.

The replay runs through the one episode loop (:func:`robobpp.episode.run_episode`) with a playback policy, and
ends and counts as the reference does (docs/benchmark.md, "Two protocols"): an action is checked against the
container on the plan's idealised pile (:class:`OpenLoop`: bounds and height, as the reference's environment
step), never against the pile as it physically stands; the setting decides the rest — a collapse, a failed
operation. On a collapse the box that caused it is not counted (boxes placed, utilisation); every box packed
before it is, displaced or not. Decision Time is the recorded one (no policy is called again). When the Math
episode ended before its last box, the replay places what Math placed and then ends as Math ended, unless the
setting ended it earlier.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from robobpp.core import (
    Action,
    Box,
    ContainerState,
    EpisodeInfo,
    EpisodeSpec,
    FinalBox,
    Observation,
    Placement,
)
from robobpp.episode import COMPLETED, EpisodeResult, StepRecord, run_episode
from robobpp.policies.base import Policy, PolicyError
from robobpp.sim import Setting, make_setting
from robobpp.sim.base import StepOutcome
from robobpp.sim.math_pack import MathPack
from robobpp.vocabulary import BOARD_TRACKS, CLOSED, LOOPS, MATH, PAPER, PHYSICAL, Loop

LOOP_DESCRIPTIONS: dict[str, str] = {
    CLOSED: "the policy observes the setting's state at every step (closed loop)",
    PAPER: "the policy plans in Math Pack, its actions are replayed open loop in the setting, as in the paper",
}


def check_loop(loop: str) -> Loop:
    """``loop`` if it is known; otherwise a ``ValueError`` naming the known ones."""
    if loop == CLOSED:
        return CLOSED
    if loop == PAPER:
        return PAPER
    raise ValueError(f"unknown protocol {loop!r}; expected one of {', '.join(LOOPS)}")


class Playback:
    """A policy that answers with recorded answers, in order, then ends the episode as the recording ended."""

    def __init__(self, name: str, answers: Sequence[Action | None], termination: str, detail: str) -> None:
        self.name = name
        self.answers = tuple(answers)
        self.termination = termination
        self.detail = detail

    def reset(self, info: EpisodeInfo) -> None:
        return None

    def act(self, obs: Observation) -> Action | None:
        if obs.step < len(self.answers):
            return self.answers[obs.step]
        # The recording ended here (its last answer, if any, was placed): end as it ended.
        raise PolicyError(self.termination, self.detail)

    def close(self, reason: str) -> None:
        return None


class OpenLoop(Setting):
    """A physical setting as the reference replays into it: each action first goes onto the idealised (Math
    Pack) pile, where the reference's environment step checks it (bounds and height: ``too_high`` there ends
    the replay); the physical setting then executes it without its own check of the height on the physical
    pile (``height_check`` off): a box may come to stand above the container, as in the reference,
    whose only other height check (its container's ``add_new_box``) reads the same idealised heights."""

    def __init__(self, setting: Setting) -> None:
        self.inner = setting
        self.name = setting.name
        self.ideal = MathPack()
        self._height_check = getattr(setting, "height_check", None)

    @property
    def physics_version(self) -> str | None:
        return self.inner.physics_version

    def reset(self, spec: EpisodeSpec) -> None:
        if self._height_check is not None:
            self.inner.height_check = False  # type: ignore[attr-defined]
        self.ideal.reset(spec)
        self.inner.reset(spec)

    def state(self) -> ContainerState:
        return self.inner.state()

    def apply(self, box: Box, action: Action, index: int) -> StepOutcome:
        planned = self.ideal.apply(box, action, index)
        if planned.termination is not None:
            return planned
        return self.inner.apply(box, action, index)

    def final_boxes(self) -> list[FinalBox]:
        return self.inner.final_boxes()

    def plan(self) -> list[Placement]:
        """The idealised pile the actions were checked on, as the reference's Occupancy reads it."""
        return list(self.ideal.state().placements)

    def close(self) -> None:
        try:
            self.inner.close()
        finally:
            if self._height_check is not None:
                self.inner.height_check = self._height_check  # type: ignore[attr-defined]


def replay_episode(
    spec: EpisodeSpec,
    setting: Setting | str,
    actions: Sequence[Action | None],
    decision_times: Sequence[float],
    *,
    policy: str = "replay",
    termination: str = COMPLETED,
    termination_detail: str = "",
) -> EpisodeResult:
    """Replay recorded answers (one per box from the first; ``None``: no feasible placement) in ``setting``.

    Each answer goes through the episode loop as a policy's would: the loop's bounds check refuses what is
    out of the container, the plan's idealised pile what is too high (:class:`OpenLoop`), the setting decides
    the rest (collapse, a failed operation) and may end the episode at any box; counted as the reference
    counts (:meth:`robobpp.episode.Episode.result`). ``decision_times[i]`` is box ``i``'s Decision Time. When the answers run
    out before the boxes, the episode ends with ``termination`` and ``termination_detail`` (how the recorded
    episode ended). The result carries ``protocol="paper"`` and the policy name ``policy``.
    """
    if len(actions) != len(decision_times):
        raise ValueError(f"{len(actions)} actions but {len(decision_times)} decision times")
    if len(actions) > len(spec.boxes):
        raise ValueError(f"{len(actions)} actions for an episode of {len(spec.boxes)} boxes")
    if termination == COMPLETED and len(actions) < len(spec.boxes):
        raise ValueError(
            f"a completed episode answers every box: {len(actions)} actions for {len(spec.boxes)} boxes"
        )
    playback = Playback(policy, actions, termination, termination_detail)
    physical = OpenLoop(make_setting(setting) if isinstance(setting, str) else setting)
    return run_episode(spec, playback, physical, decision_times=decision_times, protocol=PAPER)


def recorded_answers(math: EpisodeResult) -> tuple[list[Action | None], list[float]]:
    """The answers of a Math Pack episode to replay, and their decision times.

    Every placed box's action; then, if the episode ended on a box with "no feasible placement", that answer
    (the replay ends there exactly as Math did, its decision time counted). An action Math *refused* (out of
    bounds, too high, malformed) is not replayed: the replay ends with Math's termination after the placed
    boxes. Needs the per-step trace (``math.steps``).
    """
    answers: list[Action | None] = []
    times: list[float] = []
    for step in sorted(math.steps, key=lambda s: s.step):
        if step.step != len(answers):
            raise ValueError(f"{math.episode_id}: the trace skips from box {len(answers) - 1} to {step.step}")
        placed = step.action is not None and step.placement is not None and step.termination is None
        if placed:
            assert step.action is not None
            answers.append(
                Action(step.action["x"], step.action["y"], int(step.action["orientation"]), step.compute_time)
            )
            times.append(step.decision_time)
            continue
        if step.action is None and step.termination is not None:
            answers.append(None)
            times.append(step.decision_time)
        break
    if len(answers) < math.boxes_placed:
        raise ValueError(
            f"{math.episode_id}: {math.boxes_placed} boxes placed but {len(answers)} steps in the trace "
            "(a result without its per-step trace cannot be replayed)"
        )
    return answers, times


def replay_math_result(math: EpisodeResult, spec: EpisodeSpec, setting: Setting | str) -> EpisodeResult:
    """The paper protocol for one episode: ``math``'s actions and decision times replayed in ``setting``."""
    if math.setting != MATH:
        raise ValueError(
            f"{math.episode_id}: the paper protocol replays a Math Pack episode, not {math.setting}"
        )
    if math.episode_id != spec.episode_id:
        raise ValueError(f"the Math episode {math.episode_id} is not episode {spec.episode_id}")
    name = setting if isinstance(setting, str) else setting.name
    if name not in PHYSICAL:
        raise ValueError(f"the paper protocol replays in {' or '.join(PHYSICAL)}, not {name!r}")
    answers, times = recorded_answers(math)
    return replay_episode(
        spec,
        setting,
        answers,
        times,
        policy=math.policy,
        termination=math.termination,
        termination_detail=math.termination_detail,
    )


def run_paper_loop(
    spec: EpisodeSpec,
    policy: Policy,
    settings: Sequence[Setting | str],
    *,
    lookahead: int = 0,
    time_budget_s: float | None = None,
    math: EpisodeResult | None = None,
) -> Mapping[str, EpisodeResult]:
    """Run ``policy`` once in Math Pack (unless ``math`` already holds that episode), then replay it in each
    physical setting of ``settings`` (names, or instances set up some other way). Returns
    ``{"math": ..., setting name: ...}``; the Math episode is closed protocol (there both protocols coincide)."""
    names = [s if isinstance(s, str) else s.name for s in settings]
    for name in names:
        if name not in PHYSICAL:
            raise ValueError(f"the paper protocol replays in {' or '.join(PHYSICAL)}, not {name!r}")
    if math is None:
        math = run_episode(spec, policy, MATH, lookahead=lookahead, time_budget_s=time_budget_s)
    out: dict[str, EpisodeResult] = {MATH: math}
    for name, setting in zip(names, settings, strict=True):
        out[name] = replay_math_result(math, spec, setting)
    return out


def play(
    loop: str,
    spec: EpisodeSpec,
    policy: Policy,
    settings: Sequence[Setting | str],
    *,
    lookahead: int = 0,
    time_budget_s: float | None = None,
) -> list[EpisodeResult]:
    """``spec``'s episodes of ``policy`` in each of ``settings`` (names, or instances), in their order, under
    ``loop``: closed, one episode per setting; paper, one Math Pack episode (whether or not ``settings`` has
    Math Pack) replayed in each physical setting (:func:`run_paper_loop`). The one place the two loops part
    (``robobpp evaluate``, ``robobpp reproduce``, their worker processes)."""
    if check_loop(loop) == CLOSED:
        return [
            run_episode(spec, policy, s, lookahead=lookahead, time_budget_s=time_budget_s) for s in settings
        ]
    names = [s if isinstance(s, str) else s.name for s in settings]
    in_math = [s for s, name in zip(settings, names, strict=True) if name == MATH]
    math = run_episode(
        spec, policy, in_math[0] if in_math else MATH, lookahead=lookahead, time_budget_s=time_budget_s
    )
    physical = [s for s, name in zip(settings, names, strict=True) if name != MATH]
    runs = run_paper_loop(spec, policy, physical, math=math)
    return [runs[name] for name in names]


#: Tracks whose submissions get the paper's loop too (a verification is compared on closed loop only).
PAPER_TRACKS = BOARD_TRACKS


def paper_settings(settings: Sequence[str], track: str) -> list[str]:
    """The physical settings a server's submission also gets under the paper's loop (docs/server.md, "The
    paper protocol"): those it chose, when it chose Math Pack too (the plan is its Math episodes' actions)."""
    if MATH not in settings or track not in PAPER_TRACKS:
        return []
    return [s for s in settings if s in PHYSICAL]


#: What a plan keeps of each step of the Math Pack episode (a few numbers a box).
PLAN_STEP_KEYS = (
    "step",
    "box",
    "action",
    "decision_time",
    "compute_time",
    "round_trip",
    "network_estimate",
    "placement",
    "termination",
)
#: What a plan keeps of the Math Pack episode's ending.
PLAN_KEYS = ("termination", "termination_detail", "boxes_placed", "policy", "seed")


def plan_of(result: Mapping[str, Any]) -> dict[str, Any]:
    """What a paper-loop replay needs of a Math Pack episode's result (``EpisodeResult.to_dict()``): each
    step's action (None: the policy found no placement) and its timing, and how the episode ended. Stored on
    the replays' episodes for every track, where a private episode keeps no trace; read back by
    :func:`math_result_of`."""
    return {
        "steps": [{k: step.get(k) for k in PLAN_STEP_KEYS} for step in result.get("steps", [])],
        **{k: result.get(k) for k in PLAN_KEYS},
    }


def math_result_of(plan: Mapping[str, Any], spec: EpisodeSpec) -> EpisodeResult:
    """The Math Pack episode a plan (:func:`plan_of`) was taken from, as the replay reads it (actions, timings,
    ending)."""
    steps = [
        StepRecord(**{k: v for k, v in step.items() if v is not None or k == "action"})
        for step in plan["steps"]
    ]
    return EpisodeResult(
        episode_id=spec.episode_id,
        dataset=spec.dataset,
        split=spec.split,
        group=spec.group,
        setting=MATH,
        policy=plan.get("policy") or "",
        seed=int(plan.get("seed") or spec.seed),
        boxes_total=len(spec.boxes),
        boxes_placed=int(plan.get("boxes_placed") or 0),
        termination=plan.get("termination") or "",
        termination_detail=plan.get("termination_detail") or "",
        metrics={},
        counters={},
        container={},
        steps=steps,
    )


__all__ = [
    "CLOSED",
    "LOOP_DESCRIPTIONS",
    "PAPER",
    "PAPER_TRACKS",
    "PLAN_KEYS",
    "PLAN_STEP_KEYS",
    "OpenLoop",
    "Playback",
    "check_loop",
    "math_result_of",
    "paper_settings",
    "plan_of",
    "play",
    "recorded_answers",
    "replay_episode",
    "replay_math_result",
    "run_paper_loop",
]
