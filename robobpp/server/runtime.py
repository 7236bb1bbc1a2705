"""Per-app runtime state: the engine and session factory (created lazily, disposed at shutdown)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from functools import cached_property
from typing import Any

from sqlalchemy import Engine
from sqlalchemy.orm import Session, sessionmaker

from robobpp.db.session import make_engine, make_session_factory
from robobpp.server.config import Settings


class Runtime:
    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self.executor: Any = None

    @cached_property
    def engine(self) -> Engine:
        if not self.settings.database_url:
            self.settings.state_dir.mkdir(parents=True, exist_ok=True)
        return make_engine(self.settings.sqlalchemy_url)

    @cached_property
    def session_factory(self) -> sessionmaker[Session]:
        return make_session_factory(self.engine)

    @contextmanager
    def session(self) -> Iterator[Session]:
        """A transaction that commits on success and rolls back on error."""
        with self.session_factory() as session, session.begin():
            yield session

    def dispose(self) -> None:
        if "engine" in self.__dict__:
            self.engine.dispose()
