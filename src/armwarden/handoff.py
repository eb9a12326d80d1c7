"""Completing an asyncio future from another thread (servo loops, the audit writer).

A worker thread never touches a future directly: it asks the future's loop to settle it with
`settle_threadsafe`, and the loop side (`settle`) ignores a future whose awaiter already gave up
(cancelled or timed out), so a late result is dropped instead of raising `InvalidStateError`.
"""

from __future__ import annotations

import asyncio
from typing import Any


def settle(future: asyncio.Future[Any], result: Any = None, error: BaseException | None = None) -> None:
    """On the future's loop: set `error` if given, else `result`; nothing if it is already done."""
    if future.done():
        return
    if error is not None:
        future.set_exception(error)
    else:
        future.set_result(result)


def settle_threadsafe(
    loop: asyncio.AbstractEventLoop, future: asyncio.Future[Any], result: Any = None, error: BaseException | None = None
) -> bool:
    """From any thread: have `loop` settle `future`. False if the loop is closed (nobody waits any more)."""
    try:
        loop.call_soon_threadsafe(settle, future, result, error)
    except RuntimeError:  # the loop was closed
        return False
    return True


__all__ = ["settle", "settle_threadsafe"]
