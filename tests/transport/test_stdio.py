"""The stdio gate (`transport/stdio.py`) between the SDK's stdio streams and the server: unreadable
lines and requests whose id is still open are answered by the gate; everything else passes on."""

from __future__ import annotations

import json
from typing import Any

import anyio
import mcp_types as types
import pytest
from mcp.shared._context_streams import create_context_streams
from mcp.shared.message import ServerMessageMetadata, SessionMessage
from pydantic import ValidationError

from armwarden.transport.jsonrpc import INVALID_REQUEST, PARSE_ERROR, RefusedRequest, StopTaken
from armwarden.transport.stdio_gate import gate_streams


def request(request_id: Any, method: str = "tools/call", name: str = "execute_plan") -> SessionMessage:
    return SessionMessage(types.JSONRPCRequest(jsonrpc="2.0", id=request_id, method=method,
                                               params={"name": name, "arguments": {"plan_id": "p"}}))


def answer(request_id: Any) -> SessionMessage:
    return SessionMessage(types.JSONRPCResponse(jsonrpc="2.0", id=request_id, result={}))


def unreadable(line: str) -> Exception:
    try:
        types.jsonrpc_message_adapter.validate_json(line, by_name=False)
    except ValidationError as exc:
        return exc
    raise AssertionError(f"{line!r} is a valid message")


class Wire:
    """The gate between in-memory streams: `client` feeds what stdin would carry, `server` is what
    the SDK's server reads, `sent` is what went to stdout, `refused` what was reported."""

    def __init__(self) -> None:
        self.stdin_send, stdin_receive = create_context_streams[SessionMessage | Exception](16)
        stdout_send, self.stdout_receive = anyio.create_memory_object_stream[SessionMessage](16)
        self.refused: list[tuple[str, Any, Any]] = []
        self.stops: list[tuple[str, Any]] = []
        self.outcomes: list[tuple[str, str]] = []
        self.taken: list[tuple[StopTaken, ...]] = []
        self.latches: list[tuple[Any, Any, str]] = []

        def on_estop_refused(reason: Any, principal: Any, why: str) -> int:
            self.latches.append((reason, principal, why))
            return len(self.latches)

        async def on_refused(refused: RefusedRequest) -> None:
            self.refused.append((refused.method, refused.params, refused.request_id))
            self.outcomes.append((refused.outcome, refused.why))
            self.taken.append(refused.stops)

        def spawn(fn, *args) -> None:
            self.spawned.append((fn, args))

        self.spawned: list[tuple[Any, tuple]] = []
        self.server_read, self.server_write = gate_streams(stdin_receive, stdout_send, spawn, on_refused,
                                                           lambda tool, principal: self.stops.append((tool, principal)),
                                                           on_estop_refused=on_estop_refused)

    async def client(self, item: SessionMessage | Exception) -> None:
        await self.stdin_send.send(item)

    async def passed(self) -> SessionMessage:
        with anyio.fail_after(5):
            item = await self.server_read.receive()
        assert isinstance(item, SessionMessage)
        return item

    async def passed_request(self) -> types.JSONRPCRequest:
        message = (await self.passed()).message
        assert isinstance(message, types.JSONRPCRequest)
        return message

    def sent(self) -> list[Any]:
        out = []
        while True:
            try:
                out.append(self.stdout_receive.receive_nowait().message)
            except anyio.WouldBlock:
                return out

    async def report(self) -> None:
        for fn, args in self.spawned:
            await fn(*args)


@pytest.mark.anyio
async def test_a_request_reusing_an_open_id_is_answered_with_an_error_and_not_passed_on() -> None:
    wire = Wire()
    await wire.client(request(7))
    await wire.client(request(7, name="gripper_home"))
    await wire.client(request(8))
    assert (await wire.passed_request()).id == 7
    assert (await wire.passed_request()).id == 8  # the duplicate never reached the server
    [refusal] = wire.sent()
    assert isinstance(refusal, types.JSONRPCError) and refusal.id == 7
    assert refusal.error.code == INVALID_REQUEST and "already in use by an open request" in refusal.error.message


@pytest.mark.anyio
async def test_the_refused_duplicate_is_reported_with_its_method_and_params() -> None:
    wire = Wire()
    await wire.client(request(7))
    await wire.client(request(7, name="gripper_home"))
    await wire.client(request(8))
    await wire.passed()
    await wire.passed()
    await wire.report()
    assert wire.refused == [("tools/call", {"name": "gripper_home", "arguments": {"plan_id": "p"}}, 7)]


@pytest.mark.anyio
@pytest.mark.parametrize("reused", ["7", "07", " 7"])
async def test_ids_the_sdk_matches_as_one_are_one_open_id(reused: str) -> None:
    wire = Wire()
    await wire.client(request(7))
    await wire.client(request(reused))
    await wire.client(request(8))
    await wire.passed()
    assert (await wire.passed_request()).id == 8
    [refusal] = wire.sent()
    assert refusal.id == reused and refusal.error.code == INVALID_REQUEST


@pytest.mark.anyio
async def test_an_id_is_free_again_once_its_answer_is_written() -> None:
    wire = Wire()
    await wire.client(request(7))
    await wire.passed()
    await wire.server_write.send(answer(7))
    await wire.client(request(7))
    assert (await wire.passed_request()).id == 7
    assert [type(m) for m in wire.sent()] == [types.JSONRPCResponse]


@pytest.mark.anyio
async def test_an_id_is_free_again_once_its_request_settles_unanswered() -> None:
    # a cancelled request is never answered: the SDK runs the request's on_request_unanswered hook
    wire = Wire()
    await wire.client(request(7))
    first = await wire.passed()
    assert isinstance(first.metadata, ServerMessageMetadata) and first.metadata.on_request_unanswered is not None
    await first.metadata.on_request_unanswered()
    await wire.client(request(7))
    assert (await wire.passed_request()).id == 7
    assert wire.sent() == []


@pytest.mark.anyio
@pytest.mark.parametrize(("line", "code"), [("this is not json", PARSE_ERROR), ('{"foo": 1}', INVALID_REQUEST)])
async def test_an_unreadable_line_is_answered_with_id_null_and_the_next_message_passes(line: str, code: int) -> None:
    wire = Wire()
    await wire.client(unreadable(line))
    await wire.client(request(1))
    assert (await wire.passed_request()).id == 1
    [error] = wire.sent()
    assert isinstance(error, types.JSONRPCError) and error.id is None and error.error.code == code


@pytest.mark.anyio
async def test_notifications_and_client_answers_pass_unchanged() -> None:
    wire = Wire()
    cancel = SessionMessage(types.JSONRPCNotification(jsonrpc="2.0", method="notifications/cancelled",
                                                      params={"requestId": 7}))
    await wire.client(cancel)
    await wire.client(answer(3))  # the client's answer to a server request (another id space)
    assert (await wire.passed()) is cancel
    assert (await wire.passed()).message == answer(3).message
    assert wire.sent() == []


@pytest.mark.anyio
@pytest.mark.parametrize("tool", ["estop", "stop_motion"])
async def test_a_stop_request_holds_the_robot_as_it_is_read(tool: str) -> None:
    wire = Wire()
    await wire.client(request(1, name=tool))
    assert wire.stops == []  # nothing before the gate reads it
    assert (await wire.passed_request()).params["name"] == tool  # and it still reaches the server
    assert wire.stops == [(tool, None)]


@pytest.mark.anyio
@pytest.mark.parametrize(("method", "name"), [("tools/call", "execute_plan"), ("tools/call", "get_safety_status"),
                                              ("tools/list", "estop")])
async def test_other_requests_do_not_stop_the_robot(method: str, name: str) -> None:
    wire = Wire()
    await wire.client(request(1, method=method, name=name))
    await wire.passed_request()
    assert wire.stops == []


@pytest.mark.anyio
async def test_a_stop_request_holds_the_robot_even_when_its_id_is_refused() -> None:
    wire = Wire()
    await wire.client(request(1, name="execute_plan"))
    await wire.passed_request()
    await wire.client(request(1, name="estop"))  # the open motion call's id: refused by the gate, yet it stops
    await wire.client(request(2, name="get_robot_state"))
    await wire.passed_request()
    assert wire.stops == [("estop", None)]
    assert wire.sent()[0].error.code == INVALID_REQUEST


def call(request_id: Any, name: str, arguments: Any) -> SessionMessage:
    return SessionMessage(types.JSONRPCRequest(jsonrpc="2.0", id=request_id, method="tools/call",
                                               params={"name": name, "arguments": arguments}))


@pytest.mark.anyio
@pytest.mark.parametrize("arguments", [["person in the cell"], "person in the cell", 3])
async def test_an_estop_whose_arguments_are_not_an_object_reaches_the_tool_with_them_as_its_reason(arguments: Any) -> None:
    """Found by review: the SDK refuses such params before any tool runs, so the arm was held on
    receipt but the e-stop never latched and nothing was recorded."""
    wire = Wire()
    await wire.client(call(3, "estop", arguments))
    passed = await wire.passed_request()
    assert passed.params == {"name": "estop", "arguments": {"reason": arguments}}
    assert wire.stops == [("estop", None)]
    await wire.report()
    assert wire.refused == []


@pytest.mark.anyio
async def test_a_stop_motion_whose_arguments_are_not_an_object_reaches_the_tool() -> None:
    wire = Wire()
    await wire.client(call(4, "stop_motion", ["now"]))
    assert (await wire.passed_request()).params == {"name": "stop_motion", "arguments": {"given": ["now"]}}


@pytest.mark.anyio
async def test_a_call_with_malformed_params_is_reported_and_left_for_the_sdk_to_answer() -> None:
    wire = Wire()
    await wire.client(call(5, "gripper_move", [0.04]))
    passed = await wire.passed_request()  # the SDK answers it -32602
    await wire.report()
    assert passed.id == 5
    assert wire.refused == [("tools/call", {"name": "gripper_move", "arguments": [0.04]}, 5)]
    assert wire.outcomes == [("invalid_params", "tools/call of gripper_move refused: its arguments are not an object")]


@pytest.mark.anyio
async def test_an_unreadable_line_is_reported() -> None:
    wire = Wire()
    await wire.client(unreadable("{not json"))
    await wire.client(request(1))
    await wire.passed()
    await wire.report()
    assert wire.refused == [(None, None, None)]
    assert wire.outcomes[0][0] == "unreadable"


# ------------------------------------------------------------------ an estop that will not run still latches
@pytest.mark.anyio
async def test_an_estop_whose_id_is_refused_latches_before_the_refusal_is_answered() -> None:
    wire = Wire()
    await wire.client(request(1, name="execute_plan"))
    await wire.passed_request()
    await wire.client(call(1, "estop", {"reason": "person in the cell"}))  # the open motion call's id
    await wire.client(request(2, name="get_robot_state"))
    await wire.passed_request()
    [(reason, principal, why)] = wire.latches
    assert reason == "person in the cell" and principal is None and "already in use" in why
    await wire.report()
    assert wire.taken == [(StopTaken("estop", 1),)]  # the refusal's record says it latched


@pytest.mark.anyio
async def test_a_stop_motion_whose_id_is_refused_holds_and_latches_nothing() -> None:
    wire = Wire()
    await wire.client(request(1, name="execute_plan"))
    await wire.passed_request()
    await wire.client(call(1, "stop_motion", {}))
    await wire.client(request(2, name="get_robot_state"))
    await wire.passed_request()
    await wire.report()
    assert wire.stops == [("stop_motion", None)] and wire.latches == []
    assert wire.taken == [(StopTaken("stop_motion"),)]


@pytest.mark.anyio
async def test_an_estop_answered_with_an_error_latches_before_the_answer_is_written() -> None:
    wire = Wire()
    await wire.client(call(5, "estop", {"reason": "smoke"}))
    await wire.passed_request()
    error = types.JSONRPCError(jsonrpc="2.0", id=5, error=types.ErrorData(code=-32602, message="Invalid request parameters"))
    await wire.server_write.send(SessionMessage(error))
    [(reason, _, why)] = wire.latches
    assert reason == "smoke" and "-32602" in why
    assert wire.sent() == [error]


@pytest.mark.anyio
async def test_an_estop_answered_with_a_result_latches_nothing_here() -> None:
    wire = Wire()
    await wire.client(call(5, "estop", {"reason": "smoke"}))
    await wire.passed_request()
    await wire.server_write.send(answer(5))  # the tool ran: it latched itself
    assert wire.latches == []


@pytest.mark.anyio
async def test_an_estop_that_settles_unanswered_latches() -> None:
    wire = Wire()
    await wire.client(call(5, "estop", {"reason": "smoke"}))
    passed = await wire.passed()
    assert isinstance(passed.metadata, ServerMessageMetadata) and passed.metadata.on_request_unanswered is not None
    await passed.metadata.on_request_unanswered()  # cancelled before its tool answered
    assert [reason for reason, _, _ in wire.latches] == ["smoke"]


@pytest.mark.anyio
async def test_a_line_that_is_json_but_no_message_and_names_estop_holds_and_latches() -> None:
    wire = Wire()
    line = '{"jsonrpc": "1.0", "id": 3, "method": "tools/call", "params": {"name": "estop", "arguments": {"reason": "r"}}}'
    await wire.client(unreadable(line))
    await wire.client(request(1))
    await wire.passed()
    await wire.report()
    assert wire.stops == [("estop", None)] and [reason for reason, _, _ in wire.latches] == ["r"]
    [error] = wire.sent()
    assert error.error.code == INVALID_REQUEST
    assert wire.taken == [(StopTaken("estop", 1),)]


@pytest.mark.anyio
async def test_a_batch_line_is_refused_and_each_stop_tool_in_it_holds_and_latches_once() -> None:
    wire = Wire()
    elements = [{"jsonrpc": "2.0", "id": i, "method": "tools/call", "params": {"name": name, "arguments": {"reason": name}}}
                for i, name in enumerate(["get_robot_state", "estop", "stop_motion", "estop", "stop_motion"])]
    await wire.client(unreadable(json.dumps(elements)))
    await wire.client(request(1))
    await wire.passed()
    await wire.report()
    assert wire.stops == [("estop", None), ("stop_motion", None)]
    assert [reason for reason, _, _ in wire.latches] == ["estop"]
    [error] = wire.sent()
    assert error.id is None and error.error.code == INVALID_REQUEST and "batch" in error.error.message
    assert wire.taken == [(StopTaken("estop", 1), StopTaken("stop_motion"))]
    assert wire.outcomes[0][0] == "invalid_request"
