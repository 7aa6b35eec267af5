"""Future plumbing for handlers: results of device jobs, transformed and combined off the bus thread."""
from __future__ import annotations

from concurrent.futures import Executor, Future
from typing import Any, Callable


def chain(fut: Future, fn: Callable[[Any], Any], executor: Executor | None = None) -> Future:
    """A future of ``fn(result)``; errors pass through.

    ``fn`` runs in the thread that completed ``fut`` (a device runner) unless an
    ``executor`` is given: slow work such as writing files goes there, so it never
    holds up a device.
    """
    out: Future = Future()

    def run(result: Any) -> None:
        try:
            out.set_result(fn(result))
        except BaseException as e:  # noqa: BLE001 - handed to the client as an error reply
            out.set_exception(e)

    def done(f: Future) -> None:
        exc = f.exception()
        if exc is not None:
            out.set_exception(exc)
        elif executor is None:
            run(f.result())
        else:
            executor.submit(run, f.result())

    fut.add_done_callback(done)
    return out


def gather(futures: dict[str, Future]) -> Future:
    """A future of ``{name: result}`` once all are done; the first error wins."""
    out: Future = Future()
    remaining = [len(futures)]

    def done(_: Future) -> None:
        remaining[0] -= 1
        if remaining[0]:
            return
        for f in futures.values():
            if f.exception() is not None:
                out.set_exception(f.exception())
                return
        out.set_result({k: f.result() for k, f in futures.items()})

    if not futures:
        out.set_result({})
    for f in futures.values():
        f.add_done_callback(done)
    return out
