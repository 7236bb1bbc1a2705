"""Security headers on every page: a Content-Security-Policy, no framing, no referrer to other sites.

The pages load scripts, styles and images from this server only (``/static``, vendored); the only inline
scripts are import maps (the replay) and the API docs' start-up script, which the policy allows by their
SHA-256 hashes, computed from the body actually sent — so an injected ``<script>`` runs nowhere, and there is
no list of hashes to keep in step with the templates. Inline ``style`` attributes stay allowed (the templates
use them for layout). ``frame-ancestors 'none'`` and ``X-Frame-Options: DENY`` stop clickjacking of the
forms (sign-in, submit, cancel, revoke).
"""

from __future__ import annotations

import base64
import hashlib
import re

from starlette.types import ASGIApp, Message, Receive, Scope, Send

_INLINE_SCRIPT = re.compile(rb"<script(?P<attrs>[^>]*)>(?P<body>.*?)</script>", re.S | re.I)
#: Sent with every response (pages or not).
ALWAYS = [(b"x-content-type-options", b"nosniff"), (b"referrer-policy", b"same-origin")]


def content_security_policy(html: bytes) -> bytes:
    hashes = sorted(
        {
            "'sha256-" + base64.b64encode(hashlib.sha256(m["body"]).digest()).decode() + "'"
            for m in _INLINE_SCRIPT.finditer(html)
            if b"src=" not in m["attrs"].lower()
        }
    )
    return (
        "default-src 'self'; script-src 'self' " + " ".join(hashes) + "; style-src 'self' 'unsafe-inline'; "
        "img-src 'self' data:; connect-src 'self'; object-src 'none'; base-uri 'self'; form-action 'self'; "
        "frame-ancestors 'none'"
    ).encode()


class SecurityHeaders:
    """Pure ASGI middleware: the headers above on HTML responses, ``nosniff`` and the referrer policy on all."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        start: Message | None = None
        chunks: list[bytes] = []

        async def headed_send(message: Message) -> None:
            nonlocal start
            if message["type"] == "http.response.start":
                headers = [(k, v) for k, v in message.get("headers", []) if k.lower() not in dict(ALWAYS)]
                message = {**message, "headers": headers + ALWAYS}
                if any(k.lower() == b"content-type" and v.startswith(b"text/html") for k, v in headers):
                    start = message  # held until the body is complete: the policy hashes its scripts
                    return
            elif message["type"] == "http.response.body" and start is not None:
                chunks.append(message.get("body", b""))
                if message.get("more_body", False):
                    return
                body = b"".join(chunks)
                held, start = start, None
                await send(
                    {
                        **held,
                        "headers": [
                            *held["headers"],
                            (b"content-security-policy", content_security_policy(body)),
                            (b"x-frame-options", b"DENY"),
                        ],
                    }
                )
                message = {"type": "http.response.body", "body": body}
            await send(message)

        await self.app(scope, receive, headed_send)
