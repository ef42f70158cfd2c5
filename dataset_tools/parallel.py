"""Per-item work in worker processes: results as they finish, and a clear error when a worker dies.

``multiprocessing.Pool`` waits forever for the result of a worker that the system killed (the
out-of-memory killer sends SIGKILL); :class:`concurrent.futures.ProcessPoolExecutor` notices the
death, and :func:`imap_unordered` turns it into one :class:`ChildProcessError` (an ``OSError``,
so a command prints it as one line). Workers ignore Ctrl-C: the parent stops handing out items
and lets the running ones finish, so an interrupt leaves no half-done item behind.
"""

from __future__ import annotations

import itertools
import multiprocessing
import signal
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Any, TypeVar

Item = TypeVar("Item")
Result = TypeVar("Result")

WORKER_DIED = (
    "a worker process died (killed by the system, most likely for lack of memory); the work "
    "finished so far is kept: run the same command again to resume (fewer --workers need less "
    "memory)"
)


def _start_worker(initializer: Callable[..., Any] | None, initargs: tuple) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if initializer is not None:
        initializer(*initargs)


def imap_unordered(
    function: Callable[[Item], Result],
    items: Iterable[Item],
    workers: int,
    initializer: Callable[..., Any] | None = None,
    initargs: tuple = (),
) -> Iterator[Result]:
    """``function(item)`` for every item, in ``workers`` processes, yielded as they finish.

    With one worker the items run in this process, in order (``initializer`` is not called).
    At most ``4 * workers`` items are handed out at a time, so a long ``items`` iterator is
    never held in memory. An exception raised by ``function`` propagates (after the running
    items finish). Raises ChildProcessError (:data:`WORKER_DIED`) when a worker process dies.
    """
    if workers <= 1:
        yield from map(function, items)
        return
    method = "fork" if "fork" in multiprocessing.get_all_start_methods() else "spawn"
    executor = ProcessPoolExecutor(
        workers,
        mp_context=multiprocessing.get_context(method),
        initializer=_start_worker,
        initargs=(initializer, initargs),
    )
    queue = iter(items)
    running: set[Future] = set()
    try:
        while True:
            for item in itertools.islice(queue, 4 * workers - len(running)):
                running.add(executor.submit(function, item))
            if not running:
                return
            done, running = wait(running, return_when=FIRST_COMPLETED)
            for future in done:
                yield future.result()
    except BrokenProcessPool:
        raise ChildProcessError(WORKER_DIED) from None
    finally:
        executor.shutdown(wait=True, cancel_futures=True)
