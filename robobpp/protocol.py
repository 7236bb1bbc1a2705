"""Step protocol ``robobpp/1``: the messages between an evaluator (the caller) and a policy server.

These pydantic models are the single source of truth of the wire format: the SDK server validates
requests with them, :class:`robobpp.client.remote.RemotePolicy` validates answers with them, and the JSON
Schema (:func:`json_schema`) and the SDK server's OpenAPI document are generated from them.

Every model is strict because the other side is untrusted in both directions: unknown fields are
rejected, numbers must be finite and inside generous bounds, and ``"1"`` is not a number. Units are cm,
kg and seconds (docs/benchmark.md, "Units and frames").

Endpoints (all JSON, relative to the policy's base URL)::

    GET  /info   -> InfoResponse
    POST /reset  ResetRequest -> EmptyResponse
    POST /act    ActRequest   -> ActResponse
    POST /close  CloseRequest -> EmptyResponse

"No feasible placement" is an :class:`ActResponse` whose ``x``, ``y`` and ``orientation`` are all
``null``; a mix of numbers and nulls is a protocol violation.

Requests are signed when the submission has a secret: ``X-Robobpp-Timestamp`` is the Unix time in whole
seconds and ``X-Robobpp-Signature`` the hex HMAC-SHA256, keyed with the secret, of the timestamp's ASCII
digits followed directly by the raw request body (empty for ``GET /info``). A receiver refuses a
signature that does not match or whose timestamp lies outside the replay window.

With a secret the *answers* are signed too, and bound to the request they answer: the same two headers
on a 200 answer carry the HMAC of :func:`answer_message` — the episode id and step of the request, the
answer's timestamp, the request's own signature (unique per request) and the raw answer body. An answer
replayed from another step, episode or evaluation, or altered on the way, does not verify; the caller
ends the episode as ``protocol_violation``. docs/protocol.md shows the exact bytes.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import math
import time
from collections.abc import Mapping
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from robobpp.core import Action, Box, ContainerSpec, ContainerState, EpisodeInfo, Observation, Placement

PROTOCOL = "robobpp/1"

TIMESTAMP_HEADER = "X-Robobpp-Timestamp"
SIGNATURE_HEADER = "X-Robobpp-Signature"
PROTOCOL_HEADER = "X-Robobpp-Protocol"

#: How far (seconds) a request's timestamp may lie from the receiver's clock, either way.
DEFAULT_REPLAY_WINDOW_S = 300.0

#: Bounds of the wire format. Generous (a container is a few metres) but finite, so that a hostile
#: number is refused at the protocol layer before any geometry sees it.
MAX_CM = 10_000.0
MAX_KG = 100_000.0
MAX_COMPUTE_TIME_S = 86_400.0
MAX_BOXES = 10_000
MAX_LOOKAHEAD = 1_000
MAX_TEXT = 200

Length = Annotated[float, Field(gt=0, le=MAX_CM)]
Coordinate = Annotated[float, Field(ge=-MAX_CM, le=MAX_CM)]
Orientation = Annotated[int, Field(ge=0, le=1)]
Text = Annotated[str, Field(max_length=MAX_TEXT)]
Unit = Annotated[float, Field(ge=-1, le=1)]


class Message(BaseModel):
    """Base of every protocol message: strict, closed, finite."""

    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False, frozen=True)


class EmptyResponse(Message):
    """The answer to ``/reset`` and ``/close``: exactly ``{}``."""


#: The version ``/info`` carries when a policy reports none; labels leave it out ("dbl", not "dbl 0").
UNREPORTED_VERSION = "0"


class InfoResponse(Message):
    protocol: Literal["robobpp/1"]
    name: Text
    version: Text = UNREPORTED_VERSION


class ContainerModel(Message):
    length: Length
    width: Length
    height: Length


class BoxModel(Message):
    length: Length
    width: Length
    height: Length
    mass: Annotated[float, Field(gt=0, le=MAX_KG)]


class PlacedModel(Message):
    """One box in the container as it actually is (after physics): min corner, bottom, oriented extents."""

    x: Coordinate
    y: Coordinate
    z: Coordinate
    length: Length
    width: Length
    height: Length
    orientation: Orientation
    #: Position of the box in the episode's sequence; defaults to its position in ``placed``.
    index: Annotated[int, Field(ge=0, le=MAX_BOXES)] | None = None
    #: Actual attitude (x, y, z, w) in Physics/Execution Pack; absent or null means upright.
    quaternion: tuple[Unit, Unit, Unit, Unit] | None = None


class ResetRequest(Message):
    episode_id: Text
    dataset: Text
    setting: Text
    container: ContainerModel
    orientations: Annotated[list[Orientation], Field(min_length=1, max_length=2)] = [0, 1]
    lookahead: Annotated[int, Field(ge=0, le=MAX_LOOKAHEAD)] = 0


class ActRequest(Message):
    episode_id: Text
    step: Annotated[int, Field(ge=0, le=MAX_BOXES)]
    container: ContainerModel | None = None
    placed: Annotated[list[PlacedModel], Field(max_length=MAX_BOXES)]
    box: BoxModel
    lookahead: Annotated[list[BoxModel], Field(max_length=MAX_LOOKAHEAD)] = []
    orientations: Annotated[list[Orientation], Field(min_length=1, max_length=2)] = [0, 1]


class ActResponse(Message):
    """Where to put the box; all three of ``x``, ``y``, ``orientation`` null means "no feasible placement"."""

    x: Coordinate | None
    y: Coordinate | None
    orientation: Orientation | None
    #: Seconds the policy says it computed; kept beside the decision time the caller measures.
    compute_time: Annotated[float, Field(ge=0, le=MAX_COMPUTE_TIME_S)] | None = None

    @model_validator(mode="after")
    def _all_or_nothing(self) -> ActResponse:
        nulls = [self.x is None, self.y is None, self.orientation is None]
        if any(nulls) and not all(nulls):
            raise ValueError(
                "x, y and orientation must be all numbers (a placement) or all null (no feasible placement)"
            )
        return self

    @property
    def no_placement(self) -> bool:
        return self.x is None


class CloseRequest(Message):
    episode_id: Text
    reason: Text


class ErrorResponse(BaseModel):
    """What the SDK server answers on failure (4xx/5xx); informative only, never parsed strictly."""

    error: str
    detail: Any = None


MESSAGES: dict[str, type[BaseModel]] = {
    "InfoResponse": InfoResponse,
    "ResetRequest": ResetRequest,
    "ActRequest": ActRequest,
    "ActResponse": ActResponse,
    "CloseRequest": CloseRequest,
    "EmptyResponse": EmptyResponse,
}


def json_schema(ref_template: str = "#/$defs/{model}") -> dict[str, Any]:
    """One JSON Schema document with every message of ``robobpp/1`` under ``$defs``.

    ``ref_template`` lets the SDK server place the same definitions under OpenAPI's components.
    """
    defs: dict[str, Any] = {}
    for name, model in MESSAGES.items():
        schema = model.model_json_schema(ref_template=ref_template)
        defs.update(schema.pop("$defs", {}))
        defs[name] = schema
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": f"robobpp step protocol {PROTOCOL}",
        "$defs": defs,
    }


# ---------------------------------------------------------------- conversions (in-process ⇄ wire)


def container_dict(spec: ContainerSpec) -> dict[str, float]:
    return {"length": spec.length, "width": spec.width, "height": spec.height}


def box_dict(box: Box) -> dict[str, float]:
    return {"length": box.length, "width": box.width, "height": box.height, "mass": box.mass}


def placed_dict(p: Placement) -> dict[str, Any]:
    data: dict[str, Any] = {
        "x": p.x,
        "y": p.y,
        "z": p.z,
        "length": p.length,
        "width": p.width,
        "height": p.height,
        "orientation": p.orientation,
        "index": p.index,
    }
    if p.quaternion is not None:
        data["quaternion"] = list(p.quaternion)
    return data


def reset_payload(info: EpisodeInfo) -> dict[str, Any]:
    """The ``/reset`` body for an episode (plain dict: the caller serialises it without re-validating)."""
    return {
        "episode_id": info.episode_id,
        "dataset": info.dataset,
        "setting": info.setting,
        "container": container_dict(info.container),
        "orientations": list(info.orientations),
        "lookahead": info.lookahead,
    }


def act_payload(obs: Observation) -> dict[str, Any]:
    """The ``/act`` body for an observation. The heightmap is not sent: the receiver rebuilds it."""
    return {
        "episode_id": obs.episode_id,
        "step": obs.step,
        "container": container_dict(obs.container),
        "placed": [placed_dict(p) for p in obs.placed],
        "box": box_dict(obs.box),
        "lookahead": [box_dict(b) for b in obs.lookahead],
        "orientations": list(obs.orientations),
    }


def info_from_reset(req: ResetRequest) -> EpisodeInfo:
    c = req.container
    return EpisodeInfo(
        episode_id=req.episode_id,
        dataset=req.dataset,
        setting=req.setting,
        container=ContainerSpec(c.length, c.width, c.height),
        orientations=tuple(req.orientations),
        lookahead=req.lookahead,
    )


def _placement(p: PlacedModel, position: int) -> Placement:
    index = position if p.index is None else p.index
    return Placement(p.x, p.y, p.z, p.length, p.width, p.height, p.orientation, index, p.quaternion)


def observation_from_act(
    req: ActRequest, container: ContainerSpec | None = None, previous: Observation | None = None
) -> Observation:
    """The same :class:`Observation` the policy would get in-process; the heightmap is rebuilt from ``placed``.

    ``container`` comes from the request or, for callers that omit it, from the episode's ``/reset``.
    ``previous`` (the episode's last observation) makes the rebuild incremental when the earlier boxes
    have not moved, which is every step of Math Pack: only the new boxes are added to a copy of its
    heightmap, so the cost no longer grows with the number of boxes already placed.
    """
    if req.container is not None:
        c = req.container
        container = ContainerSpec(c.length, c.width, c.height)
    if container is None:
        raise ValueError(f"no container known for episode {req.episode_id!r}: send /reset first")
    placements = [_placement(p, i) for i, p in enumerate(req.placed)]
    known = len(previous.placed) if previous is not None else 0
    if any(p.quaternion is not None for p in placements):
        state = ContainerState(container)
        state.placements = placements
        state.heightmap = _physical_heightmap(state.heightmap.shape, placements)
    elif (
        previous is not None
        and previous.container == container
        and known <= len(placements)
        and tuple(placements[:known]) == previous.placed
    ):
        state = ContainerState(container)
        state.heightmap = previous.heightmap.copy()
        state.placements = placements[:known]
        for placement in placements[known:]:
            state.add(placement)
    else:
        state = ContainerState.from_placements(container, placements)
    heightmap = state.heightmap
    heightmap.flags.writeable = False
    return Observation(
        episode_id=req.episode_id,
        step=req.step,
        container=container,
        placed=tuple(placements),
        heightmap=heightmap,
        box=Box(req.box.length, req.box.width, req.box.height, req.box.mass),
        lookahead=tuple(Box(b.length, b.width, b.height, b.mass) for b in req.lookahead),
        orientations=tuple(req.orientations),
    )


def _physical_heightmap(shape: tuple[int, int], placements: list[Placement]) -> np.ndarray:
    """The heightmap of a Physics or Execution Pack observation, rebuilt by the function the setting builds it
    with (``robobpp.sim.physics.geometry.observed_heightmap``, the setting's defaults): each box's actual,
    possibly tilted bounds. Taking each box as axis-aligned at its corner, as Math Pack's rebuild does, showed
    a served policy a pile up to tens of cm off the one an in-process policy sees (a tilted Long Board panel
    stands cm higher; the shrink moves every box edge by a cell), so the same policy packed differently, and
    ended on too_high, when served."""
    from robobpp.sim.physics.config import PhysicsConfig  # numpy only: no pybullet
    from robobpp.sim.physics.geometry import observed_heightmap

    config = PhysicsConfig()
    return observed_heightmap(shape, placements, config.heightmap_shrink_cm, config.heightmap_resolution_cm)


def action_from_response(resp: ActResponse) -> Action | None:
    if resp.no_placement:
        return None
    assert resp.x is not None and resp.y is not None and resp.orientation is not None
    return Action(resp.x, resp.y, resp.orientation, resp.compute_time)


def response_from_action(action: Action | None, compute_time: float | None = None) -> dict[str, Any]:
    """Wire form of a policy's answer; ``compute_time`` fills in when the policy did not report one."""
    if action is None:
        data: dict[str, Any] = {"x": None, "y": None, "orientation": None}
        reported = compute_time
    else:
        data = {"x": float(action.x), "y": float(action.y), "orientation": int(action.orientation)}
        reported = action.compute_time if action.compute_time is not None else compute_time
    if reported is not None and math.isfinite(reported):
        data["compute_time"] = min(max(float(reported), 0.0), MAX_COMPUTE_TIME_S)
    return data


# ---------------------------------------------------------------- signing


class SignatureError(ValueError):
    """A request's signature is missing, malformed, wrong, or outside the replay window."""


def _key(secret: str | bytes) -> bytes:
    return secret.encode() if isinstance(secret, str) else secret


def sign(secret: str | bytes, timestamp: str | int, body: bytes) -> str:
    """Hex HMAC-SHA256 of ``timestamp`` (ASCII digits) followed by ``body``."""
    mac = hmac.new(_key(secret), str(timestamp).encode("ascii"), hashlib.sha256)
    mac.update(body)
    return mac.hexdigest()


def signed_headers(secret: str | bytes, body: bytes, now: float | None = None) -> dict[str, str]:
    """Headers that sign ``body`` at time ``now`` (default: the wall clock)."""
    timestamp = str(int(time.time() if now is None else now))
    return {TIMESTAMP_HEADER: timestamp, SIGNATURE_HEADER: sign(secret, timestamp, body)}


def _signature_headers(headers: Mapping[str, str], now: float | None, window_s: float) -> tuple[str, str]:
    """(timestamp, signature) from ``headers``, after checking their form and the replay window."""
    timestamp = headers.get(TIMESTAMP_HEADER) or headers.get(TIMESTAMP_HEADER.lower())
    signature = headers.get(SIGNATURE_HEADER) or headers.get(SIGNATURE_HEADER.lower())
    if not timestamp or not signature:
        raise SignatureError(f"missing {TIMESTAMP_HEADER} or {SIGNATURE_HEADER} header")
    if not timestamp.isascii() or not timestamp.isdigit() or len(timestamp) > 12:
        raise SignatureError(f"{TIMESTAMP_HEADER} must be Unix time in whole seconds")
    current = time.time() if now is None else now
    if abs(current - int(timestamp)) > window_s:
        raise SignatureError(
            f"stale timestamp: {abs(current - int(timestamp)):.0f} s from this server's clock "
            f"(window {window_s:g} s)"
        )
    return timestamp, signature.strip().lower()


def verify(
    secret: str | bytes,
    headers: Mapping[str, str],
    body: bytes,
    *,
    now: float | None = None,
    window_s: float = DEFAULT_REPLAY_WINDOW_S,
) -> None:
    """Raise :class:`SignatureError` unless ``headers`` carry a valid, fresh signature of ``body``.

    ``headers`` may be any case-insensitive mapping (Starlette's, httpx's) or a plain dict with the
    canonical names. The comparison is constant-time.
    """
    timestamp, signature = _signature_headers(headers, now, window_s)
    if not hmac.compare_digest(sign(secret, timestamp, body), signature):
        raise SignatureError("signature does not match the body and timestamp")


#: First line of every signed answer: a request signature can never be mistaken for an answer's.
ANSWER_CONTEXT = b"robobpp/1 answer\n"


def answer_message(
    episode_id: str, step: int | None, timestamp: int, request_signature: str, body: bytes
) -> bytes:
    """The exact bytes an answer's HMAC covers.

    ``b"robobpp/1 answer\\n"``, then the compact ASCII JSON array ``[episode_id, step, timestamp,
    request_signature]`` (``episode_id`` is ``""`` for ``/info``; ``step`` is the ``/act`` step, ``null``
    for the other endpoints; ``timestamp`` the answer's, an integer), then ``b"\\n"``, then the raw body.
    JSON quoting keeps the fields unambiguous whatever characters an episode id holds.
    """
    head = json.dumps([episode_id, step, int(timestamp), request_signature], separators=(",", ":"))
    return ANSWER_CONTEXT + head.encode("ascii") + b"\n" + body


def sign_answer(
    secret: str | bytes,
    *,
    episode_id: str,
    step: int | None,
    request_signature: str,
    body: bytes,
    now: float | None = None,
) -> dict[str, str]:
    """Headers that sign an answer ``body`` to the request signed ``request_signature``."""
    timestamp = int(time.time() if now is None else now)
    message = answer_message(episode_id, step, timestamp, request_signature.strip().lower(), body)
    mac = hmac.new(_key(secret), message, hashlib.sha256).hexdigest()
    return {TIMESTAMP_HEADER: str(timestamp), SIGNATURE_HEADER: mac}


def verify_answer(
    secret: str | bytes,
    headers: Mapping[str, str],
    body: bytes,
    *,
    episode_id: str,
    step: int | None,
    request_signature: str,
    now: float | None = None,
    window_s: float = DEFAULT_REPLAY_WINDOW_S,
) -> None:
    """Raise :class:`SignatureError` unless the answer is signed for exactly this request."""
    timestamp, signature = _signature_headers(headers, now, window_s)
    message = answer_message(episode_id, step, int(timestamp), request_signature.strip().lower(), body)
    if not hmac.compare_digest(hmac.new(_key(secret), message, hashlib.sha256).hexdigest(), signature):
        raise SignatureError(
            "the answer's signature does not match this request's episode, step and body "
            "(replayed from another request, or altered)"
        )


__all__ = [
    "DEFAULT_REPLAY_WINDOW_S",
    "MESSAGES",
    "PROTOCOL",
    "PROTOCOL_HEADER",
    "SIGNATURE_HEADER",
    "TIMESTAMP_HEADER",
    "ActRequest",
    "ActResponse",
    "BoxModel",
    "CloseRequest",
    "ContainerModel",
    "EmptyResponse",
    "InfoResponse",
    "PlacedModel",
    "ResetRequest",
    "SignatureError",
    "act_payload",
    "answer_message",
    "action_from_response",
    "info_from_reset",
    "json_schema",
    "observation_from_act",
    "reset_payload",
    "response_from_action",
    "sign",
    "sign_answer",
    "signed_headers",
    "verify",
    "verify_answer",
]
