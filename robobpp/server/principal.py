"""Who is calling: what the routes learn from the bearer token (api/deps.py) or the page session, and what the
services decide with (quota, ownership, operator-only actions)."""

from __future__ import annotations

from dataclasses import dataclass

from robobpp.db.models import Participant


@dataclass(slots=True)
class Principal:
    """Who is calling: a participant, or the operator holding the admin token."""

    participant: Participant | None
    admin: bool = False
    #: The API token's row id (participants only): the pages' signed session names it, never the token.
    token_id: int | None = None

    @property
    def participant_id(self) -> int | None:
        return self.participant.id if self.participant else None
