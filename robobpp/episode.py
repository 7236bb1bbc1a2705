"""The one episode loop: observe → policy → apply → measure.

Every use runs through here: ``robobpp evaluate`` on a laptop, the Gymnasium env (which drives the
step-wise :class:`Episode` itself) and the server's workers (which hand in a remote policy).
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

from robobpp.core import (
    Action,
    EpisodeInfo,
    EpisodeSpec,
    FinalBox,
    Infeasible,
    Observation,
    Placement,
    box_label,
    check_action,
)
from robobpp.policies.base import Policy, PolicyError
from robobpp.scoring import metrics as M
from robobpp.sim import MATH_RULES_VERSION, Setting, make_setting
from robobpp.vocabulary import CLOSED, LOOPS, PAPER

#: Termination codes. Feasibility and settings add their own (``out_of_bounds``, ``too_high``, ``collapse``...).
COMPLETED = "completed"
NO_FEASIBLE_PLACEMENT = "no_feasible_placement"
POLICY_ERROR = "policy_error"
EPISODE_TIMEOUT = "episode_timeout"
COLLAPSE = "collapse"


TERMINATION_REASONS: dict[str, str] = {
    COMPLETED: "every box was placed",
    NO_FEASIBLE_PLACEMENT: "the policy found no feasible placement for the box",
    "invalid_action": "the action was malformed (non-finite number, wrong type, unknown orientation)",
    "out_of_bounds": "the footprint lay outside the container",
    "too_high": "the box top would exceed the container height",
    COLLAPSE: "a placed box moved beyond the dataset's collapse threshold or fell off",
    POLICY_ERROR: "the policy raised an error or answered garbage",
    "policy_timeout": "the policy did not answer within the per-step time limit",
    "protocol_violation": "the remote policy broke protocol robobpp/1",
    EPISODE_TIMEOUT: "the episode exceeded its total time budget",
    "failed_grasp": "the suction gripper could not hold the box",
    "place_plan_failed": "the robot could not start its place move (no IK solution, or the arm in collision)",
    "dangerous_operations": "the robot's third dangerous operation",
}

#: Each reason as a table cell names it ("collapse 18, no place 12": robobpp/export.py, docs/baselines.md).
TERMINATION_SHORT: dict[str, str] = {
    COMPLETED: "done",
    NO_FEASIBLE_PLACEMENT: "no place",
    "invalid_action": "invalid action",
    "out_of_bounds": "out of bounds",
    "too_high": "too high",
    COLLAPSE: "collapse",
    POLICY_ERROR: "policy error",
    "policy_timeout": "policy timeout",
    "protocol_violation": "protocol violation",
    EPISODE_TIMEOUT: "episode timeout",
    "failed_grasp": "failed grasp",
    "place_plan_failed": "no place plan",
    "dangerous_operations": "dangerous ops",
}


@dataclass(slots=True)
class StepRecord:
    """One step of the per-step trace (JSON-friendly)."""

    step: int
    box: dict[str, float]
    action: dict[str, float] | None
    decision_time: float
    compute_time: float | None = None
    #: A remote policy's raw round trip around ``act`` and the evaluator's network estimate for it; the
    #: decision time is then their difference (``None`` for an in-process policy).
    round_trip: float | None = None
    network_estimate: float | None = None
    placement: dict[str, Any] | None = None
    termination: str | None = None
    static_stability: float | None = None
    collapsed: bool = False
    trajectory_length_m: float | None = None
    dangerous: bool | None = None
    extra: dict[str, Any] = field(default_factory=dict)


@dataclass(slots=True)
class EpisodeResult:
    episode_id: str
    dataset: str
    split: str
    group: int
    setting: str
    policy: str
    seed: int
    boxes_total: int
    boxes_placed: int
    termination: str
    termination_detail: str
    metrics: dict[str, float | None]
    counters: dict[str, int]
    container: dict[str, float]
    steps: list[StepRecord] = field(default_factory=list)
    final: list[dict[str, Any]] = field(default_factory=list)
    #: ``Setting.physics_version`` of the setting that produced it (None: Math Pack, or recorded before
    #: versions existed).
    physics_version: str | None = None
    #: ``robobpp.sim.MATH_RULES_VERSION`` of the rules it ran under (None: recorded before versions existed).
    rules_version: str | None = None
    #: ``EpisodeSpec.sampler_version``: the sampler that drew its boxes (None: boxes not drawn by it).
    sampler_version: str | None = None
    #: How the episode was run: ``closed`` (the policy observed this setting's state at every step) or
    #: ``paper`` (its Math Pack actions replayed open loop here, :mod:`robobpp.replay`).
    protocol: str = CLOSED

    def to_dict(self, trace: bool = True) -> dict[str, Any]:
        data = asdict(self)
        if not trace:
            data.pop("steps")
            data.pop("final")
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> EpisodeResult:
        data = dict(data)
        data["steps"] = [StepRecord(**s) for s in data.get("steps", [])]
        data.setdefault("final", [])
        return cls(**data)


@dataclass(frozen=True, slots=True)
class EpisodeFigures:
    """What an episode's result counts: boxes placed (as its protocol counts them), how it ended, its metrics."""

    boxes_placed: int
    termination: Infeasible
    metrics: dict[str, float | None]


def placement_dict(p: Placement) -> dict[str, Any]:
    return {
        "x": p.x,
        "y": p.y,
        "z": p.z,
        "length": p.length,
        "width": p.width,
        "height": p.height,
        "orientation": p.orientation,
        "index": p.index,
        "quaternion": p.quaternion,
    }


class Episode:
    """Step-wise episode: call :meth:`observe`, then :meth:`step` with the policy's answer, until done."""

    def __init__(
        self, spec: EpisodeSpec, setting: Setting | str, *, lookahead: int = 0, protocol: str = CLOSED
    ) -> None:
        if (
            protocol not in LOOPS
        ):  # how the episode is played (robobpp.vocabulary.Loop; paper: Episode.result)
            raise ValueError(f"unknown protocol {protocol!r}; expected one of {', '.join(LOOPS)}")
        self.spec = spec
        self.protocol = protocol
        self.setting = make_setting(setting) if isinstance(setting, str) else setting
        self.lookahead = lookahead
        self.setting.reset(spec)
        self.index = 0
        self.termination: Infeasible | None = None
        self.steps: list[StepRecord] = []
        self.counters = {
            "placements_attempted": 0,
            "placements_collapsed": 0,
            "operations": 0,
            "operations_dangerous": 0,
        }
        self._static: list[float] = []
        self._trajectory: list[float] = []
        self._decision: list[float] = []
        self._round_trip: list[float] = []
        self._network: list[float] = []

    @property
    def info(self) -> EpisodeInfo:
        return EpisodeInfo(
            self.spec.episode_id,
            self.spec.dataset,
            self.setting.name,
            self.spec.container,
            lookahead=self.lookahead,
        )

    @property
    def done(self) -> bool:
        return self.termination is not None or self.index >= len(self.spec.boxes)

    def observe(self) -> Observation:
        """The current state as the policy sees it. Its heightmap is a read-only copy: it stays what it was
        when observed while the episode goes on, and a policy that writes to it gets an error."""
        state = self.setting.state()
        heightmap = state.heightmap.copy()
        heightmap.flags.writeable = False
        boxes = self.spec.boxes
        return Observation(
            episode_id=self.spec.episode_id,
            step=self.index,
            container=self.spec.container,
            placed=tuple(state.placements),
            heightmap=heightmap,
            box=boxes[self.index],
            lookahead=tuple(boxes[self.index + 1 : self.index + 1 + self.lookahead]),
        )

    def end(self, reason: str, detail: str) -> None:
        """End the episode early (policy failure, time budget) with a recorded reason."""
        if self.termination is None:
            self.termination = Infeasible(reason, detail)

    def step(
        self,
        action: Action | None,
        decision_time: float,
        *,
        round_trip: float | None = None,
        network_estimate: float | None = None,
    ) -> StepRecord:
        """Apply the policy's answer for the current box; ``None`` means "no feasible placement"."""
        assert not self.done, "episode is over"
        box = self.spec.boxes[self.index]
        self._decision.append(decision_time)
        if round_trip is not None:
            self._round_trip.append(round_trip)
        if network_estimate is not None:
            self._network.append(network_estimate)
        record = StepRecord(
            step=self.index,
            box={"length": box.length, "width": box.width, "height": box.height, "mass": box.mass},
            action=None,
            decision_time=decision_time,
            round_trip=round_trip,
            network_estimate=network_estimate,
        )
        self.steps.append(record)
        if action is None:
            self.end(
                NO_FEASIBLE_PLACEMENT,
                f"no feasible placement for {box_label(self.index)} "
                f"({box.length:g} × {box.width:g} × {box.height:g} cm)",
            )
            record.termination = NO_FEASIBLE_PLACEMENT
            return record
        record.action = {"x": action.x, "y": action.y, "orientation": action.orientation}
        record.compute_time = action.compute_time
        refused = check_action(action.x, action.y, action.orientation, box, self.spec.container)
        if refused is not None:
            self.termination = refused
            record.termination = refused.reason
            return record
        outcome = self.setting.apply(box, action, self.index)
        self.counters["placements_attempted"] += 1
        if outcome.collapsed:
            self.counters["placements_collapsed"] += 1
        if outcome.dangerous is not None:
            self.counters["operations"] += 1
            self.counters["operations_dangerous"] += int(outcome.dangerous)
        if outcome.static_stability is not None:
            self._static.append(outcome.static_stability)
        if outcome.trajectory_length_m is not None:
            self._trajectory.append(outcome.trajectory_length_m)
        record.placement = placement_dict(outcome.placement) if outcome.placement else None
        record.static_stability = outcome.static_stability
        record.collapsed = outcome.collapsed
        record.trajectory_length_m = outcome.trajectory_length_m
        record.dangerous = outcome.dangerous
        record.extra = dict(outcome.extra)
        if outcome.termination is not None:
            self.termination = outcome.termination
            record.termination = outcome.termination.reason
        self.index += 1
        return record

    def figures(self) -> EpisodeFigures:
        """The episode's figures as its result records them, without the trace (the Gym env's terminal info)."""
        return self._figures(self.setting.final_boxes())

    def _figures(self, world: list[FinalBox]) -> EpisodeFigures:
        final = world
        container = self.spec.container
        under = self.setting.under_volumes()
        decision, static = self._decision, self._static
        utilization = M.space_utilization(final, container)
        if self.protocol == PAPER and self.termination is not None and self.termination.reason == COLLAPSE:
            # Counted as the reference counts (its Feasible Num and utilisation): the box whose placement
            # collapsed is not placed (nor its decision time, nor its static stability), and every box
            # packed before it is, displaced or not — the paper's tables mean that. The trace keeps it
            # (``final`` in the result is every box in the world).
            final, decision, static = final[:-1], decision[:-1], static[:-1]
            utilization = M.placed_volume(final) / container.volume
        metrics: dict[str, float | None] = {
            "space_utilization": utilization,
            "occupancy": M.occupancy(
                self.setting.plan()[: len(final)], container, None if under is None else under[: len(final)]
            ),
            "decision_time": sum(decision) / len(decision) if decision else None,
        }
        if self._round_trip:  # a remote policy: the raw figures beside the decision time they gave
            metrics["round_trip"] = sum(self._round_trip) / len(self._round_trip)
        if self._network:
            metrics["network_estimate"] = sum(self._network) / len(self._network)
        if self.setting.name in M.PHYSICAL:
            metrics["local_stability"] = M.local_stability_m(final)
            metrics["static_stability"] = sum(static) / len(static) if static else None
        if self.setting.name == "execution":
            metrics["trajectory_length"] = (
                sum(self._trajectory) / len(self._trajectory) if self._trajectory else None
            )
            c = self.counters
            metrics["collapsed_placement"] = (
                c["placements_collapsed"] / c["placements_attempted"] if c["placements_attempted"] else None
            )
            metrics["dangerous_operation"] = (
                c["operations_dangerous"] / c["operations"] if c["operations"] else None
            )
        termination = self.termination or Infeasible(COMPLETED, TERMINATION_REASONS[COMPLETED])
        return EpisodeFigures(len(final), termination, metrics)

    def result(self, policy_name: str) -> EpisodeResult:
        world = self.setting.final_boxes()
        figures = self._figures(world)
        container = self.spec.container
        return EpisodeResult(
            episode_id=self.spec.episode_id,
            dataset=self.spec.dataset,
            split=self.spec.split,
            group=self.spec.group,
            setting=self.setting.name,
            policy=policy_name,
            seed=self.spec.seed,
            boxes_total=len(self.spec.boxes),
            boxes_placed=figures.boxes_placed,
            termination=figures.termination.reason,
            termination_detail=figures.termination.detail,
            metrics=figures.metrics,
            counters=dict(self.counters),
            container={"length": container.length, "width": container.width, "height": container.height},
            physics_version=self.setting.physics_version,
            rules_version=MATH_RULES_VERSION,
            sampler_version=self.spec.sampler_version,
            protocol=self.protocol,
            steps=self.steps,
            final=[
                {
                    "planned": placement_dict(f.planned),
                    "actual": placement_dict(f.actual),
                    "in_place": f.in_place,
                }
                for f in world
            ],
        )


def step_timing(policy: Policy) -> tuple[float | None, float | None]:
    """A remote policy's (round trip, network estimate) of its last ``act``; ``(None, None)`` in-process.

    :class:`~robobpp.client.remote.RemotePolicy` times the exchange itself and estimates the network's
    share with echo probes on the same connection (docs/protocol.md, "Decision time").
    """
    round_trip = getattr(policy, "last_round_trip", None)
    network = getattr(policy, "last_network_estimate", None)
    ok = isinstance(round_trip, float) and (network is None or isinstance(network, float))
    return (round_trip, network) if ok else (None, None)


def run_episode(
    spec: EpisodeSpec,
    policy: Policy,
    setting: Setting | str,
    *,
    lookahead: int = 0,
    time_budget_s: float | None = None,
    on_step: Callable[[StepRecord], None] | None = None,
    clock: Callable[[], float] = time.perf_counter,
    decision_times: Sequence[float] | None = None,
    protocol: str = CLOSED,
) -> EpisodeResult:
    """Run one episode to its end. Policy failures end the episode with a reason; nothing escapes.

    ``decision_times``: recorded decision times (one per box, in order) that stand for the measured ones: a
    replay's answers cost nothing, the decisions were made (and timed) when the actions were planned.
    ``protocol``: recorded with the result; ``paper`` also counts as the reference does (:meth:`Episode.result`).
    """
    episode = Episode(spec, setting, lookahead=lookahead, protocol=protocol)
    started = clock()
    try:
        try:
            policy.reset(episode.info)
        except PolicyError as exc:
            episode.end(exc.reason, exc.detail)
        except Exception as exc:  # noqa: BLE001 - a user policy may raise anything
            episode.end(POLICY_ERROR, f"reset raised {type(exc).__name__}: {exc}")
        while not episode.done:
            if time_budget_s is not None and clock() - started > time_budget_s:
                episode.end(EPISODE_TIMEOUT, f"episode exceeded its {time_budget_s:g} s budget")
                break
            obs = episode.observe()
            t0 = clock()
            try:
                action = policy.act(obs)
            except PolicyError as exc:
                episode.end(exc.reason, exc.detail)
                break
            except Exception as exc:  # noqa: BLE001
                episode.end(POLICY_ERROR, f"act raised {type(exc).__name__}: {exc}")
                break
            decision = clock() - t0
            if action is not None and not isinstance(action, Action):
                episode.end(POLICY_ERROR, f"act returned {type(action).__name__}, expected Action or None")
                break
            round_trip, network = step_timing(policy)
            if round_trip is not None and network is not None:
                decision = max(0.0, round_trip - network)  # the network's share is not the policy's time
            if decision_times is not None:
                decision = decision_times[episode.index]
            record = episode.step(action, decision, round_trip=round_trip, network_estimate=network)
            if on_step is not None:
                on_step(record)
        result = episode.result(getattr(policy, "name", type(policy).__name__))
    finally:
        reason = episode.termination.reason if episode.termination else COMPLETED
        with contextlib.suppress(Exception):  # closing must not turn a result into a crash
            policy.close(reason)
        episode.setting.close()
    return result
