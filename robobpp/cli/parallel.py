"""Episodes of `robobpp evaluate` on several worker processes (``--jobs N``).

Each worker loads the policy once (by the same name the user gave) and runs whole episodes through the one
episode loop; results come back in task order, so the output does not depend on ``--jobs``. Decision time is
measured inside each worker, as in a single process.
"""

from __future__ import annotations

import functools
import multiprocessing
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ProcessPoolExecutor
from typing import Any

from robobpp.core import EpisodeSpec
from robobpp.episode import EpisodeResult
from robobpp.replay import play
from robobpp.vocabulary import CLOSED

_policy: Any = None


def _load(name: str, kwargs: dict[str, Any]) -> None:
    global _policy
    from robobpp.cli.common import import_from_cwd
    from robobpp.client.loading import load_policy

    import_from_cwd(name)
    _policy = load_policy(name, **kwargs)


def _run(spec: EpisodeSpec, settings: tuple[str, ...], lookahead: int, loop: str) -> list[dict[str, Any]]:
    return [r.to_dict() for r in play(loop, spec, _policy, settings, lookahead=lookahead)]


def _report_done(on_done: Callable[[int], None], index: int, _future: Future[Any]) -> None:
    on_done(index)


def run_parallel(
    policy: str,
    policy_kwargs: dict[str, Any],
    tasks: Sequence[tuple[EpisodeSpec, tuple[str, ...]]],
    *,
    jobs: int,
    lookahead: int = 0,
    loop: str = CLOSED,
    on_done: Callable[[int], None] | None = None,
) -> Iterator[list[EpisodeResult]]:
    """Results of ``tasks`` ((spec, settings) pairs), in order; ``on_done(i)`` as each one finishes.

    Each task's episodes under ``loop`` (a :data:`robobpp.vocabulary.Loop`), all in the same worker
    (:func:`robobpp.replay.play`).
    """
    # spawn, not fork: a forked child would inherit whatever simulator state the parent holds.
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(
        jobs, mp_context=context, initializer=_load, initargs=(policy, policy_kwargs)
    ) as pool:
        futures = [pool.submit(_run, spec, settings, lookahead, loop) for spec, settings in tasks]
        if on_done is not None:
            for i, future in enumerate(futures):
                future.add_done_callback(functools.partial(_report_done, on_done, i))
        for future in futures:
            yield [EpisodeResult.from_dict(r) for r in future.result()]
