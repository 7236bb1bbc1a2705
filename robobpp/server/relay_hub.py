"""This API process's side of the pull relay: its bus and the caps' counts of its open client connections.

Made with the app (:mod:`robobpp.server.state`); the relay's routes (:mod:`robobpp.server.api.pull`) use it.
"""

from __future__ import annotations

import asyncio
import hashlib
from collections import defaultdict

from robobpp.server.relay_bus import PARTICIPANT_BUS_CALLS, LocalBus, RedisBus


class PullHub:
    """This process's side of the relay: its bus and the caps' counts of its open client connections.

    The caps are per API process, like the connection limits (server/connections.py): they bound what one
    process holds open (file handles, memory), which is what a flood of idle sockets costs. Below them, each
    participant's connections share :data:`~robobpp.server.relay_bus.PARTICIPANT_BUS_CALLS` bus calls in
    flight (:meth:`bus_slot`): however many connections one participant opens at once, it holds that many
    of the broker's pooled connections at most, and the others' calls still find one.
    """

    def __init__(self, bus: LocalBus) -> None:
        self.bus = bus
        self._started = False
        self._starting = asyncio.Lock()
        #: Open client connections (idle or busy) per submission and per participant: the caps' counts.
        self.open_per_submission: defaultdict[int, int] = defaultdict(int)
        self.open_per_participant: defaultdict[int, int] = defaultdict(int)
        self._bus_slots: dict[int, asyncio.Semaphore] = {}

    def bus_slot(self, participant_id: int) -> asyncio.Semaphore:
        """What a participant's client connections hold around each call to the bus (see the class)."""
        slot = self._bus_slots.get(participant_id)
        if slot is None:
            slot = self._bus_slots[participant_id] = asyncio.Semaphore(PARTICIPANT_BUS_CALLS)
        return slot

    async def start(self) -> PullHub:
        async with self._starting:
            if not self._started:
                await self.bus.start()
                self._started = True
        return self

    async def close(self) -> None:
        """Close the bus, if a client connection started it."""
        if self._started:
            await self.bus.close()

    def admit(
        self, submission_id: int, participant_id: int, per_submission: int, per_participant: int
    ) -> bool:
        """Count a new client connection in, unless its submission or participant is at its cap (a flood of
        idle sockets costs file handles and memory, and serves nothing: one per episode served at once)."""
        if (
            self.open_per_submission[submission_id] >= per_submission
            or self.open_per_participant[participant_id] >= per_participant
        ):
            return False
        self.open_per_submission[submission_id] += 1
        self.open_per_participant[participant_id] += 1
        return True

    def leave(self, submission_id: int, participant_id: int) -> None:
        for table, key in (
            (self.open_per_submission, submission_id),
            (self.open_per_participant, participant_id),
        ):
            table[key] -= 1
            if table[key] <= 0:
                del table[key]
        if participant_id not in self.open_per_participant:
            self._bus_slots.pop(participant_id, None)


def make_bus(broker_url: str, database_url: str) -> LocalBus:
    """The bus a deployment's settings call for: Redis or RabbitMQ when one is configured, else in-process.

    ``database_url`` names the deployment: every API process of one deployment shares its database, and two
    deployments sharing one broker (tests, staging beside production) never see each other's sockets.
    """
    if not broker_url:
        return LocalBus()
    deployment = hashlib.sha256(database_url.encode()).hexdigest()[:16]
    if broker_url.startswith(("amqp://", "amqps://", "pyamqp://")):
        from robobpp.server.relay_amqp import AmqpBus

        return AmqpBus(broker_url, deployment)
    return RedisBus(broker_url, deployment)
