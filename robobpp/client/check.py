"""Conformance check of a policy server: does it speak ``robobpp/1`` the way the evaluator will?

It asks ``/info``, probes the signature handling (when a secret is given), sends one malformed request,
then drives a short episode exactly as the server's workers would and closes it: by default a fixed Math Pack
episode in the Diverse container (no data needed); with ``dataset``/``setting`` the first boxes of that
dataset's first train group in that setting, so a policy built for one container is checked on it. Every
finding is kept, in plain words, so a participant sees all problems at once rather than one per run.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from dataclasses import dataclass, field
from typing import Literal

import httpx

from robobpp import protocol as P
from robobpp.client.remote import RemotePolicy
from robobpp.core import Box, ContainerSpec, EpisodeSpec
from robobpp.episode import COMPLETED, NO_FEASIBLE_PLACEMENT, Episode
from robobpp.policies.base import PolicyError

Level = Literal["ok", "warning", "violation"]

#: Termination codes that mean the server broke the protocol or failed, as opposed to packing badly.
_FAILURES = {"protocol_violation", "policy_error", "policy_timeout", "episode_timeout", "invalid_action"}


@dataclass(frozen=True, slots=True)
class Finding:
    level: Level
    check: str
    message: str


@dataclass(slots=True)
class CheckReport:
    url: str
    findings: list[Finding] = field(default_factory=list)
    steps: int = 0
    latencies_s: list[float] = field(default_factory=list)

    @property
    def violations(self) -> list[Finding]:
        return [f for f in self.findings if f.level == "violation"]

    @property
    def ok(self) -> bool:
        return not self.violations

    def add(self, level: Level, check: str, message: str) -> None:
        self.findings.append(Finding(level, check, message))


def check_spec(boxes: int = 8) -> EpisodeSpec:
    """A fixed, deterministic episode in the Diverse container: mixed sizes, all placeable."""
    sizes = [
        (40, 30, 20),
        (25, 25, 25),
        (60, 40, 15),
        (30, 20, 10),
        (50, 50, 30),
        (20, 15, 12),
        (45, 35, 25),
        (35, 30, 18),
    ]
    picked = [sizes[i % len(sizes)] for i in range(boxes)]
    items = tuple(Box(float(length), float(width), float(height), 2.0) for length, width, height in picked)
    return EpisodeSpec("protocol-check", "train", 0, items, ContainerSpec(120, 100, 170), 4.0, 0)


def dataset_check_spec(dataset: str, boxes: int = 8) -> EpisodeSpec:
    """The first ``boxes`` boxes of ``dataset``'s first train group (seed 0): its container, its boxes.

    Raises :class:`~robobpp.datasets.DatasetError` for an unknown dataset or data that cannot be loaded.
    """
    from robobpp.datasets import episode_specs

    spec = episode_specs(dataset, split="train", groups=1, seed=0)[0]
    return dataclasses.replace(spec, boxes=spec.boxes[:boxes])


def _probe(url: str, headers: dict[str, str], timeout_s: float, body: bytes = b"") -> httpx.Response | str:
    try:
        with httpx.Client(timeout=timeout_s, follow_redirects=False, trust_env=False) as client:
            if body:
                return client.post(url, content=body, headers={**headers, "Content-Type": "application/json"})
            return client.get(url, headers=headers)
    except httpx.HTTPError as exc:
        return f"{type(exc).__name__}: {exc}"


def _check_signatures(report: CheckReport, base: str, secret: str, timeout_s: float) -> None:
    probes = {
        "unsigned request": {},
        "wrong signature": P.signed_headers(secret + "-not", b""),
        "stale timestamp": P.signed_headers(secret, b"", now=time.time() - 10 * P.DEFAULT_REPLAY_WINDOW_S),
    }
    for label, headers in probes.items():
        answer = _probe(base + "/info", headers, timeout_s)
        if isinstance(answer, str):
            report.add("violation", "signature", f"{label}: the request failed instead of a 401 ({answer})")
        elif answer.status_code in (401, 403):
            report.add("ok", "signature", f"{label} refused with HTTP {answer.status_code}")
        else:
            report.add(
                "violation",
                "signature",
                f"{label} was answered HTTP {answer.status_code}; it must be refused with 401",
            )


def _check_malformed(report: CheckReport, base: str, secret: str | None, timeout_s: float) -> None:
    body = json.dumps(
        {"episode_id": "protocol-check", "step": 0, "placed": [], "box": {"length": "ten"}}
    ).encode()
    headers = P.signed_headers(secret, body) if secret is not None else {}
    answer = _probe(base + "/act", headers, timeout_s, body)
    if isinstance(answer, str):
        report.add("warning", "malformed request", f"a malformed /act broke the connection ({answer})")
    elif 400 <= answer.status_code < 500:
        report.add("ok", "malformed request", f"a malformed /act was refused with HTTP {answer.status_code}")
    else:
        report.add(
            "warning",
            "malformed request",
            f"a malformed /act got HTTP {answer.status_code}; a 4xx (e.g. 422) tells callers what is wrong",
        )


def check_policy_server(
    url: str,
    secret: str | None = None,
    *,
    boxes: int = 8,
    step_timeout_s: float = 10.0,
    resolved_ip: str | None = None,
    spec: EpisodeSpec | None = None,
    setting: str = "math",
) -> CheckReport:
    """Run every check against the policy server at ``url``; never raises for a misbehaving server.

    The episode is ``spec`` (default :func:`check_spec`) in ``setting``."""
    report = CheckReport(url)
    policy = RemotePolicy(
        url, secret, step_timeout_s=step_timeout_s, resolved_ip=resolved_ip, check_info=False
    )
    base = policy.url
    try:
        info = policy.fetch_info()
        report.add("ok", "info", f"speaks {info.protocol} as {info.name!r} version {info.version!r}")
    except PolicyError as exc:
        report.add("violation", "info", exc.detail)
    finally:
        policy.close("check")
    if secret is not None:
        _check_signatures(report, base, secret, step_timeout_s)
    else:
        report.add("warning", "signature", "no secret given: signature handling not checked")
    _check_malformed(report, base, secret, step_timeout_s)
    _check_episode(report, policy, spec or check_spec(boxes), setting)
    return report


def _check_episode(report: CheckReport, policy: RemotePolicy, spec: EpisodeSpec, setting: str) -> None:
    episode = Episode(spec, setting, lookahead=1)
    try:
        policy.reset(episode.info)
    except PolicyError as exc:
        report.add("violation", "reset", exc.detail)
        policy.close("check")
        episode.setting.close()
        return
    report.add("ok", "reset", "accepted /reset")
    try:
        while not episode.done:
            obs = episode.observe()
            started = time.perf_counter()
            action = policy.act(obs)
            report.latencies_s.append(time.perf_counter() - started)
            record = episode.step(action, report.latencies_s[-1])
            report.steps += 1
            if (
                action is not None
                and action.compute_time is not None
                and not math.isfinite(action.compute_time)
            ):
                report.add("violation", "act", f"step {record.step}: compute_time is not finite")
    except PolicyError as exc:
        episode.end(exc.reason, exc.detail)
    finally:
        episode.setting.close()  # a physics setting holds a simulator
    reason = episode.termination.reason if episode.termination else COMPLETED
    detail = episode.termination.detail if episode.termination else "every box was placed"
    if reason in _FAILURES:
        report.add("violation", "act", f"{reason}: {detail}")
    elif reason in (COMPLETED, NO_FEASIBLE_PLACEMENT):
        report.add("ok", "act", f"{report.steps} well-formed answers ({detail})")
    else:  # a well-formed answer that the geometry refused: the protocol is fine, the packing is not
        report.add("warning", "act", f"{reason}: {detail}")
    try:
        policy.close(reason, strict=True)
        report.add("ok", "close", "accepted /close")
    except PolicyError as exc:
        report.add("violation", "close", exc.detail)
