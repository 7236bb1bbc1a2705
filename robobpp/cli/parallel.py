"""Episodes of `robobpp evaluate` on several worker processes (``--jobs N``).

Each worker loads the policy once (by the same name the user gave) and runs whole episodes through the one
episode loop; results come back in task order, so the output does not depend on ``--jobs``. Decision time is
measured inside each worker, as in a single process.
"""

from __future__ import annotations

import multiprocessing
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from typing import Any

from robobpp.core import EpisodeSpec
from robobpp.episode import EpisodeResult, run_episode

_policy: Any = None


def _load(name: str, kwargs: dict[str, Any]) -> None:
    global _policy
    from robobpp.cli.common import import_from_cwd
    from robobpp.client.loading import load_policy

    import_from_cwd(name)
    _policy = load_policy(name, **kwargs)


def _run(spec: EpisodeSpec, setting: str, lookahead: int) -> dict[str, Any]:
    return run_episode(spec, _policy, setting, lookahead=lookahead).to_dict()


def run_parallel(
    policy: str,
    policy_kwargs: dict[str, Any],
    tasks: Sequence[tuple[EpisodeSpec, str]],
    *,
    jobs: int,
    lookahead: int = 0,
    on_done: Callable[[int], None] | None = None,
) -> Iterator[EpisodeResult]:
    """Results of ``tasks`` ((spec, setting) pairs), in order; ``on_done(i)`` as each one finishes."""
    # spawn, not fork: a forked child would inherit whatever simulator state the parent holds.
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(
        jobs, mp_context=context, initializer=_load, initargs=(policy, policy_kwargs)
    ) as pool:
        futures = [pool.submit(_run, spec, setting, lookahead) for spec, setting in tasks]
        if on_done is not None:
            for i, future in enumerate(futures):
                future.add_done_callback(lambda _f, i=i: on_done(i))
        for future in futures:
            yield EpisodeResult.from_dict(future.result())
