"""Per-app runtime state: the engine and session factory (created lazily, disposed at shutdown)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from functools import cached_property
from typing import Any

from sqlalchemy import Engine
from sqlalchemy.orm import Session, sessionmaker

from robobpp.db.session import is_sqlite, make_engine, make_session_factory
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
    def read_engine(self) -> Engine:
        """Reads only: on SQLite its own deferred, ``query_only`` connections (db/session.py)."""
        if not is_sqlite(self.settings.sqlalchemy_url):
            return self.engine
        self.engine  # noqa: B018 - creates the state directory and the database first
        return make_engine(self.settings.sqlalchemy_url, read_only=True)

    @cached_property
    def session_factory(self) -> sessionmaker[Session]:
        return make_session_factory(self.engine)

    @cached_property
    def read_session_factory(self) -> sessionmaker[Session]:
        return make_session_factory(self.read_engine)

    @contextmanager
    def read_session(self) -> Iterator[Session]:
        """A read-only transaction (never waits for the writers on SQLite)."""
        with self.read_session_factory() as session, session.begin():
            yield session

    @contextmanager
    def session(self) -> Iterator[Session]:
        """A transaction that commits on success and rolls back on error."""
        with self.session_factory() as session, session.begin():
            yield session

    def dispose(self) -> None:
        for name in ("read_engine", "engine"):
            if name in self.__dict__:
                self.__dict__[name].dispose()
