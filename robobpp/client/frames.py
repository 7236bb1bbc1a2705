"""Pull mode's frames: a ``robobpp/1`` request or answer inside one binary WebSocket message.

A frame is one line of JSON (the envelope: id, method and path, or status; the headers) followed by the
raw HTTP body, so the body travels byte for byte as in push mode and its signature still verifies::

    {"id":7,"method":"POST","path":"/act","headers":[["X-Robobpp-Signature","…"],…]}\\n{"episode_id":…}
    {"id":7,"status":200,"headers":[["content-type","application/json"]]}\\n{"x":0.0,"y":30.0,…}

The worker numbers its requests; an answer carries the number it answers, so a late answer to a request
the worker gave up on is recognised and dropped.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

#: Longest envelope line accepted (headers are a handful of short strings).
MAX_ENVELOPE = 4096


@dataclass(frozen=True, slots=True)
class Frame:
    id: int
    envelope: dict[str, Any]
    headers: list[tuple[str, str]]
    body: bytes


def encode(envelope: dict[str, Any], headers: list[tuple[str, str]], body: bytes) -> bytes:
    line = json.dumps({**envelope, "headers": [[k, v] for k, v in headers]}, separators=(",", ":"))
    return line.encode() + b"\n" + body


def decode(data: bytes) -> Frame:
    """Parse a frame; ``ValueError`` with a plain reason when it is not one."""
    head, sep, body = data.partition(b"\n")
    if not sep or len(head) > MAX_ENVELOPE:
        raise ValueError("no envelope line (JSON, then a newline, then the body)")
    try:
        envelope = json.loads(head)
    except ValueError:
        raise ValueError("the envelope line is not JSON") from None
    if (
        not isinstance(envelope, dict)
        or isinstance(envelope.get("id"), bool)
        or not isinstance(envelope.get("id"), int)
    ):
        raise ValueError("the envelope has no integer 'id'")
    raw = envelope.pop("headers", [])
    if not isinstance(raw, list) or not all(
        isinstance(h, list) and len(h) == 2 and all(isinstance(x, str) for x in h) for h in raw
    ):
        raise ValueError("the envelope's 'headers' must be a list of [name, value] strings")
    return Frame(envelope["id"], envelope, [(k, v) for k, v in raw], body)
