"""Engines and sessions for SQLite (embedded default) and PostgreSQL (scaled).

SQLite is shared by the API process and the worker processes, so every writing transaction starts with
``BEGIN IMMEDIATE`` (one writer at a time, waiting on the busy timeout instead of failing on a lock
upgrade) and the journal is WAL so readers never block the writer. Reads (``read_only=True``: the API's
GET routes, ``/healthz``) take a plain deferred ``BEGIN`` on ``query_only`` connections instead: a WAL
reader needs no lock, so it never queues behind the writers (a read waited 7 s behind them under 20
concurrent readers during an evaluation before; see BENCHMARKS.md, "SQLite reads").
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import orjson
from sqlalchemy import Engine, create_engine, event
from sqlalchemy.orm import Session, sessionmaker


def is_sqlite(url: str) -> bool:
    return url.startswith("sqlite")


def make_engine(url: str, *, read_only: bool = False, **kwargs: Any) -> Engine:
    if is_sqlite(url):
        if read_only:  # one connection per concurrent reader; they cost a file handle each
            kwargs.setdefault("pool_size", 20)
            kwargs.setdefault("max_overflow", 20)
        engine = create_engine(url, connect_args={"timeout": 60, "check_same_thread": False}, **kwargs)

        @event.listens_for(engine, "connect")
        def _on_connect(dbapi_connection: Any, _record: Any) -> None:
            dbapi_connection.isolation_level = None  # let SQLAlchemy's BEGIN below drive transactions
            cursor = dbapi_connection.cursor()
            cursor.execute("PRAGMA busy_timeout=60000")
            # WAL is a property of the file: set once. Asking for it again on every new connection could fail
            # at once with "database is locked" while another connection was writing (the busy timeout does
            # not cover it): a test's first write lost that race against the dispatcher's.
            if str(cursor.execute("PRAGMA journal_mode").fetchone()[0]).lower() != "wal":
                cursor.execute("PRAGMA journal_mode=WAL")
            cursor.execute("PRAGMA synchronous=NORMAL")
            cursor.execute("PRAGMA foreign_keys=ON")
            if read_only:
                cursor.execute("PRAGMA query_only=ON")
            cursor.close()

        @event.listens_for(engine, "begin")
        def _on_begin(conn: Any) -> None:
            conn.exec_driver_sql("BEGIN" if read_only else "BEGIN IMMEDIATE")

        return engine
    kwargs.setdefault("pool_pre_ping", True)
    kwargs.setdefault("pool_size", 10)
    kwargs.setdefault("max_overflow", 20)
    # PostgreSQL's JSON holds no NaN nor Infinity, so orjson reads all of it, 3-4 times faster than the
    # standard library (the board engine's start reads 300,000 documents at 10,000 submissions)
    kwargs.setdefault("json_deserializer", orjson.loads)
    return create_engine(url, **kwargs)


def make_session_factory(engine: Engine) -> sessionmaker[Session]:
    return sessionmaker(engine, expire_on_commit=False)


@contextmanager
def transaction(factory: sessionmaker[Session]) -> Iterator[Session]:
    """One unit of work: commit on success, roll back on any error (no half-written rows)."""
    with factory() as session, session.begin():
        yield session
