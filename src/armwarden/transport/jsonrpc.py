"""JSON-RPC facts both transports share: error codes, the request-id collision rule, refusal wording.

Lean on purpose (no Starlette, no uvicorn): the stdio transport imports it.
"""

from __future__ import annotations

import logging
from collections.abc import Awaitable, Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from mcp.shared.dispatcher import coerce_request_id

from armwarden.tools import names

logger = logging.getLogger(__name__)

#: the line is not JSON
PARSE_ERROR = -32700
#: JSON, but not a request this server takes (not a JSON-RPC message, or an id already open)
INVALID_REQUEST = -32600
#: the params do not fit the method
INVALID_PARAMS = -32602
#: 2026-07-28 over HTTP: a routing header (`Mcp-Method`, `Mcp-Name`, ...) disagrees with the body
HEADER_MISMATCH = -32020


def request_id_key(request_id: Any) -> str:
    """The key under which the SDK files a request id: it matches answers and cancellations with
    7, "7" and "07" as one id, so two open requests must never share this key."""
    if isinstance(request_id, (int, str)) and not isinstance(request_id, bool):
        return str(coerce_request_id(request_id))
    return str(request_id)


#: tools whose request stops the robot the moment the transport reads it, before it is queued
STOP_TOOLS = names(lambda spec: spec.stops_on_read)
#: (tool, principal or None): hold the robot now; the tool itself runs later and does the rest
StopOnReceipt = Callable[[str, "str | None"], None]
#: (reason, principal or None, why) -> the e-stop event number: latch the e-stop for an `estop`
#: request that was read but will not run — refused before its tool saw it, or ended without it
#: (docs/threat-model.md: a clumsy stop still latches; a release needs a human, so latching is
#: always safe). `reason` is what the request gave, any value. Quick, never waits for the disk,
#: records itself; must not raise (a stop that could not be issued latches on top and is recorded).
LatchOnRefusal = Callable[[Any, "str | None", str], int]


@dataclass(frozen=True)
class StopTaken:
    """What a refused request's call of a stopping tool did to the robot as it was read: `estop`
    latched `estop_event` (None: nobody to latch it, tests only); `stop_motion` held the arm, which
    is all that tool does. Such a refusal's record is never left out of the log."""

    tool: str
    estop_event: int | None = None

    def describe(self) -> str:
        if self.tool != "estop":
            return f"the {self.tool} request held the robot as it was read"
        if self.estop_event is None:
            return "the estop request held the robot as it was read (no latch here)"
        return f"e-stop #{self.estop_event} latched: a refused estop request still latches"


@dataclass(frozen=True)
class RefusedRequest:
    """A request a transport refused, or knows the SDK will refuse, before the server's tools saw
    it — its id was open or unusable, it was unreadable (method, params and id then None), its
    `tools/call` params were malformed, the SDK answered it with an error — for the audit log."""

    method: Any
    params: Mapping[str, Any] | None
    request_id: Any
    outcome: str
    why: str
    #: what its stop calls did (`StopTaken`)
    stops: tuple[StopTaken, ...] = ()
    #: a batch (a JSON array, which no MCP revision takes): what its elements ask for, the tool of
    #: a `tools/call`, else the method (at most `BATCH_NAMES_KEPT`); None: not a batch
    batch: tuple[str, ...] | None = None
    #: who sent it: the principal the transport authenticated (HTTP with tokens), the session it
    #: claimed (the session header, unchecked: the SDK checks it later, if at all), its host (HTTP)
    principal: str | None = None
    session: str | None = None
    peer: str | None = None


#: awaited (HTTP, before the answer) or run soon after (stdio) for each `RefusedRequest`
RefusedCallback = Callable[[RefusedRequest], Awaitable[None]]


def stop_call(method: Any, params: Any) -> str | None:
    """The tool name if this is a `tools/call` request of a stopping tool, else None."""
    if method != "tools/call" or not isinstance(params, dict):
        return None
    name = params.get("name")
    return name if isinstance(name, str) and name in STOP_TOOLS else None


def estop_reason(params: Any) -> Any:
    """The reason an `estop` call's params give (any value; None when they give none): its
    `arguments.reason`, or `arguments` itself when that is not an object (`stop_params_repaired`)."""
    arguments = params.get("arguments") if isinstance(params, Mapping) else None
    return arguments.get("reason") if isinstance(arguments, Mapping) else arguments


def refused_stops(stop_calls: Iterable[tuple[str, Any]], latch: LatchOnRefusal | None, principal: str | None,
                  why: str) -> tuple[StopTaken, ...]:
    """What the stop calls (tool, params) of a request that will not reach its tools did: each was
    held as it was read (`screen_call`); an `estop` among them now latches too — once per request,
    with the first one's reason. Call it before the refusal is answered."""
    taken: dict[str, StopTaken] = {}
    for tool, params in stop_calls:
        if tool in taken:
            continue
        event = None
        if tool == "estop" and latch is not None:
            try:
                event = latch(estop_reason(params), principal, why)
            except Exception:  # the hook records its own failures; a bug there must not eat the refusal
                logger.exception("latching the e-stop for a refused estop request failed")
        taken[tool] = StopTaken(tool, event)
    return tuple(taken.values())


def stop_params_repaired(tool: str, params: dict[str, Any]) -> dict[str, Any]:
    """The params of a `tools/call` of the stopping `tool` (see `stop_call`) as they go on: the
    same object, unless its `arguments` is not an object (a list, a string, a number) — then a
    copy with that value kept under an argument the tool takes, `reason` for `estop`, `given` for
    `stop_motion` (stopping tools accept any), so the call reaches the tool, which latches or
    holds and is audited like any other. The SDK refuses such params (-32602) before any tool or
    the audit sees them: the arm was held on receipt, but the e-stop never latched and nothing
    said why."""
    arguments = params.get("arguments")
    if arguments is None or isinstance(arguments, dict):
        return params
    return {**params, "arguments": {"reason" if tool == "estop" else "given": arguments}}


def malformed_call(method: Any, params: Any) -> str | None:
    """Why the SDK will refuse this `tools/call` request (-32602) before any tool, and so before
    the audit middleware, sees it: params that are not an object, no tool name (a string), or
    `arguments` that are neither an object nor absent. None: well formed, or not a `tools/call`.
    The transports audit these refusals themselves."""
    if method != "tools/call":
        return None
    if not isinstance(params, dict):
        return "tools/call refused: its params are not an object"
    if not isinstance(params.get("name"), str):
        return "tools/call refused: no tool name (a string)"
    arguments = params.get("arguments")
    if arguments is not None and not isinstance(arguments, dict):
        return f"tools/call of {str(params['name'])[:64]} refused: its arguments are not an object"
    return None


#: how many of a batch's elements a refusal names
BATCH_NAMES_KEPT = 16


def batch_refusal(size: int) -> str:
    """Why a batch is refused, on both transports (JSON-RPC -32600, id null)."""
    return (f"Invalid Request: a JSON-RPC batch ({size} elements) is not accepted: no MCP revision this server "
            "speaks has batches; none of its calls ran (a stop or e-stop among them has taken effect). "
            "Send each request on its own.")


def screen_batch(elements: list[Any], on_stop_request: StopOnReceipt | None,
                 principal: str | None) -> tuple[list[tuple[str, Any]], tuple[str, ...]]:
    """`screen_call` for every element of a batch, which will be refused as a whole: each stopping
    tool named holds the robot once (the first of its calls; a batch of thousands of stops is one
    hold, not thousands). Returns the (tool, params) of those first stop calls, for
    `refused_stops`, and what the elements ask for (`RefusedRequest.batch`)."""
    stops: dict[str, Any] = {}
    names: list[str] = []
    for element in elements:
        method = element.get("method") if isinstance(element, dict) else None
        params = element.get("params") if isinstance(element, dict) else None
        if len(names) < BATCH_NAMES_KEPT:
            name = params.get("name") if method == "tools/call" and isinstance(params, dict) else method
            names.append(str(name)[:64] if name is not None else "?")
        tool = stop_call(method, params)
        if tool is not None and tool not in stops:
            stops[tool] = screen_call(method, params, on_stop_request, principal)[0]
    return list(stops.items()), tuple(names)


def screen_call(method: Any, params: Any, on_stop_request: StopOnReceipt | None,
                principal: str | None) -> tuple[Any, str | None]:
    """What both transports do with a request the moment it is read, before the SDK: a stopping
    tool's call holds the robot at once (`on_stop_request`) and is repaired if its arguments are
    not an object (`stop_params_repaired`); any other `tools/call` the SDK will refuse before the
    tools see it is named (`malformed_call`), for the audit. Returns (the params to pass on — the
    same object unless repaired —, why the SDK will refuse it or None)."""
    tool = stop_call(method, params)
    if tool is None:
        return params, malformed_call(method, params)
    if on_stop_request is not None:
        on_stop_request(tool, principal)  # hold the robot now, even if the request is refused later
    return stop_params_repaired(tool, params), None


def usable_request_id(request_id: Any) -> bool:
    """Whether a request id can be answered: a string or an integer (the SDK's `RequestId`). A
    message without one (null, true, 1.0, or no id at all) is a notification to the SDK."""
    return isinstance(request_id, (int, str)) and not isinstance(request_id, bool)


def unanswerable_call(method: Any, params: Any) -> str | None:
    """Why a request of `method` sent without a usable id (`usable_request_id`) is refused, for a
    `tools/call`; None for any other method. The SDK would take such a call for a notification
    and drop it: the tool would not run and the client would never know (an `estop` sent that
    way did not latch). Both transports refuse it with -32600 Invalid Request, id null, and
    audit it; a stopping tool's call has already held the robot as it was read (`screen_call`),
    and an `estop` latches as it is refused (`refused_stops`)."""
    if method != "tools/call":
        return None
    name = params.get("name") if isinstance(params, dict) else None
    tool = str(name)[:64] if isinstance(name, str) else "a tool"
    return (f"Invalid Request: tools/call of {tool} refused: it has no usable id (a string or an integer; "
            "not null, true or 1.0, and not left out), so it could not be answered; the tool did not run. "
            "Send it again with an id.")


def duplicate_id_message(request_id: Any) -> str:
    """Why a request was refused: its id is still open. Without the refusal the SDK would replace
    the open call's entry, and that call (perhaps a motion) could no longer be cancelled."""
    return f"request id {str(request_id)[:64]} is already in use by an open request of this session"
