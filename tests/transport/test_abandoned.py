"""`AbandonedMotionStop`: a motion call whose request ends without its response is cancelled in its
own session (the `notifications/cancelled` the client would have sent goes through the same app)
and reported once; answered calls, other tools, other paths are left alone; oversized bodies are
refused before the app sees them."""

from __future__ import annotations

import contextlib
import json
from types import SimpleNamespace
from typing import Any

import anyio
import pytest

from armwarden.transport.abandoned import AbandonedMotionStop, motion_call
from armwarden.transport.jsonrpc import RefusedRequest, StopTaken
from armwarden.transport.mcp_middleware import LatchEstopsNotRun
from armwarden.transport.request_body import MAX_BODY_BYTES, decode_message

SESSION = (b"mcp-session-id", b"s-123")


def rpc(name: str, arguments: Any = None, method: str = "tools/call", request_id: Any = 7) -> bytes:
    message = {"jsonrpc": "2.0", "method": method, "params": {"name": name, "arguments": arguments if arguments is not None else {}}}
    if request_id is not None:
        message["id"] = request_id
    return json.dumps(message).encode()


class Recorder:
    """The wrapped app: reads the body, streams part of an answer, then answers in full or not.
    Every request it sees is kept (the injected cancellation among them)."""

    def __init__(self, answer: bool, fail: bool = False, cancel_status: int = 202) -> None:
        self.answer, self.fail, self.cancel_status = answer, fail, cancel_status
        self.seen: list[tuple[dict, bytes]] = []

    async def __call__(self, scope, receive, send) -> None:
        body, more = b"", True
        while more:
            message = await receive()
            body += message.get("body", b"")
            more = message.get("more_body", False)
        self.seen.append((scope, body))
        if json.loads(body).get("method") == "notifications/cancelled":
            await send({"type": "http.response.start", "status": self.cancel_status, "headers": []})
            await send({"type": "http.response.body", "body": b""})
            return
        await send({"type": "http.response.start", "status": 200, "headers": []})
        await send({"type": "http.response.body", "body": b"event: progress", "more_body": True})
        if self.fail:
            raise RuntimeError("the client went away mid-stream")
        if self.answer:
            await send({"type": "http.response.body", "body": b"event: result", "more_body": False})


async def run(body: bytes, app: Recorder, *, path: str = "/mcp", method: str = "POST", headers=(SESSION,),
        chunk: int | None = None) -> tuple[list[tuple], list[dict]]:
    reports: list[tuple] = []
    responses: list[dict] = []

    async def on_abandoned(tool: str, arguments: dict, request_id: Any, cancelled: bool) -> None:
        reports.append((tool, arguments, request_id, cancelled))

    size = chunk or max(1, len(body))
    pieces = [body[i:i + size] for i in range(0, len(body), size)] or [b""]
    messages = [{"type": "http.request", "body": piece, "more_body": i < len(pieces) - 1} for i, piece in enumerate(pieces)]

    async def receive() -> dict:
        return messages.pop(0) if messages else {"type": "http.disconnect"}

    async def send(message: dict) -> None:
        responses.append(message)

    middleware = AbandonedMotionStop(app, "/mcp", on_abandoned)

    with contextlib.suppress(RuntimeError):  # a recorder told to fail mid-stream
        await middleware({"type": "http", "method": method, "path": path, "headers": list(headers)}, receive, send)
    return reports, responses


def cancellations(app: Recorder) -> list[dict]:
    return [json.loads(body) for _scope, body in app.seen if json.loads(body).get("method") == "notifications/cancelled"]


@pytest.mark.anyio
@pytest.mark.parametrize("tool", ["execute_plan", "gripper_move", "gripper_grasp", "gripper_home"])
async def test_an_unanswered_motion_call_is_cancelled_in_its_session_and_reported(tool):
    app = Recorder(answer=False)
    reports, _ = await run(rpc(tool, {"plan_id": "plan_x"}, request_id="r-1"), app)
    assert [c["params"]["requestId"] for c in cancellations(app)] == ["r-1"]
    cancel_scope = app.seen[-1][0]
    assert SESSION in cancel_scope["headers"]  # the same session, so only this client's call is touched
    assert reports == [(tool, {"plan_id": "plan_x"}, "r-1", True)]


@pytest.mark.anyio
async def test_a_motion_call_whose_stream_broke_is_cancelled():
    app = Recorder(answer=False, fail=True)
    reports, _ = await run(rpc("execute_plan", {"plan_id": "p"}), app)
    assert len(cancellations(app)) == 1 and reports == [("execute_plan", {"plan_id": "p"}, 7, True)]


@pytest.mark.anyio
async def test_a_body_that_arrives_in_pieces_reaches_the_app_whole():
    app = Recorder(answer=True)
    body = rpc("execute_plan", {"plan_id": "p"})
    await run(body, app, chunk=5)
    assert app.seen[0][1] == body


@pytest.mark.anyio
async def test_an_answered_motion_call_is_left_alone():
    app = Recorder(answer=True)
    reports, _ = await run(rpc("execute_plan", {"plan_id": "p"}), app)
    assert reports == [] and cancellations(app) == []


@pytest.mark.anyio
async def test_a_refused_cancellation_is_reported_as_not_delivered():
    app = Recorder(answer=False, cancel_status=404)
    reports, _ = await run(rpc("execute_plan", {"plan_id": "p"}), app)
    assert reports == [("execute_plan", {"plan_id": "p"}, 7, False)]


@pytest.mark.anyio
async def test_without_a_session_nothing_is_injected_and_the_call_is_reported_as_ended_with_its_request():
    # 2026-07-28 requests carry no session: the SDK cancels the call itself when its request ends
    app = Recorder(answer=False)
    reports, _ = await run(rpc("execute_plan", {"plan_id": "p"}), app, headers=())
    assert cancellations(app) == [] and reports == [("execute_plan", {"plan_id": "p"}, 7, None)]


@pytest.mark.anyio
@pytest.mark.parametrize("body", [rpc("get_robot_state"), rpc("plan_to_pose"), rpc("execute_plan", method="tools/list"),
                                  rpc("execute_plan", request_id=None), rpc("execute_plan", request_id=True)])
async def test_other_messages_are_never_cancelled(body):
    app = Recorder(answer=False)
    reports, _ = await run(body, app)
    assert reports == [] and cancellations(app) == []


@pytest.mark.anyio
async def test_other_paths_and_methods_are_passed_through_untouched():
    app = Recorder(answer=False)
    assert (await run(rpc("execute_plan", {"plan_id": "p"}), app, path="/healthz"))[0] == []
    assert (await run(rpc("execute_plan", {"plan_id": "p"}), app, method="GET"))[0] == []
    assert cancellations(app) == []


@pytest.mark.anyio
async def test_an_oversized_body_is_refused_with_413_and_never_reaches_the_app():
    app = Recorder(answer=True)
    reports, responses = await run(rpc("execute_plan", {"plan_id": "p", "pad": "x" * MAX_BODY_BYTES}), app, chunk=65536)
    assert responses[0]["status"] == 413 and app.seen == [] and reports == []


@pytest.mark.parametrize("body", [b"not json", b"[1, 2]", b""])
def test_bodies_that_are_not_calls_are_not_motion_calls(body):
    assert motion_call(decode_message(body)) is None


def test_non_object_arguments_become_an_empty_mapping():
    assert motion_call(decode_message(rpc("execute_plan", ["plan_x"]))) == ("execute_plan", {}, 7)


@pytest.mark.anyio
async def test_a_declared_oversized_body_is_refused_before_it_is_read():
    app = Recorder(answer=True)
    read: list[dict] = []
    responses: list[dict] = []

    async def receive() -> dict:
        read.append({})
        return {"type": "http.request", "body": b"{}", "more_body": False}

    async def send(message: dict) -> None:
        responses.append(message)

    scope = {"type": "http", "method": "POST", "path": "/mcp",
             "headers": [SESSION, (b"content-length", str(50 * MAX_BODY_BYTES).encode())]}
    await AbandonedMotionStop(app, "/mcp")(scope, receive, send)
    assert responses[0]["status"] == 413 and read == [] and app.seen == []


@pytest.mark.anyio
@pytest.mark.parametrize("reused", [777, "777", "0777"])
async def test_a_request_id_already_open_in_the_session_is_refused_and_the_open_call_stays_cancellable(reused):
    class Holding(Recorder):
        """Keeps the first call open until told; answers everything else at once."""

        def __init__(self) -> None:
            super().__init__(answer=True)
            self.release = anyio.Event()

        async def __call__(self, scope, receive, send) -> None:
            if not self.seen:
                self.seen.append((scope, b'{"method": "tools/call"}'))
                await self.release.wait()
                return  # ends unanswered: the client went away
            await super().__call__(scope, receive, send)

    app = Holding()
    reports: list[tuple] = []

    async def on_abandoned(*report) -> None:
        reports.append(report)

    middleware = AbandonedMotionStop(app, "/mcp", on_abandoned)
    statuses: list[int] = []

    def request(body: bytes):
        async def receive() -> dict:
            return {"type": "http.request", "body": body, "more_body": False}

        async def send(message: dict) -> None:
            if message["type"] == "http.response.start":
                statuses.append(message["status"])

        return middleware({"type": "http", "method": "POST", "path": "/mcp", "headers": [SESSION]}, receive, send)

    async with anyio.create_task_group() as group:
        group.start_soon(request, rpc("execute_plan", {"plan_id": "p"}, request_id=777))
        await anyio.sleep(0.01)
        await request(rpc("get_safety_status", request_id=reused))  # 7, "7" and "07" are one id to the SDK
        await request(rpc("get_safety_status", request_id=778))
        app.release.set()
    assert statuses[:2] == [409, 200]
    assert [c["params"]["requestId"] for c in cancellations(app)] == [777]
    assert reports == [("execute_plan", {"plan_id": "p"}, 777, True)]


async def pass_through(body: bytes) -> tuple[Recorder, list[tuple]]:
    """`body` through the middleware with an on_refused recorder; what the app saw, what was refused."""
    app, refused = Recorder(answer=True), []

    async def on_refused(r: RefusedRequest) -> None:
        refused.append((r.method, r.params, r.request_id, r.outcome, r.why))

    messages = [{"type": "http.request", "body": body, "more_body": False}]

    async def receive() -> dict:
        return messages.pop(0) if messages else {"type": "http.disconnect"}

    async def send(message: dict) -> None:
        pass

    middleware = AbandonedMotionStop(app, "/mcp", on_refused=on_refused)
    headers = [SESSION, (b"content-length", str(len(body)).encode())]
    await middleware({"type": "http", "method": "POST", "path": "/mcp", "headers": headers}, receive, send)
    return app, refused


@pytest.mark.anyio
async def test_an_estop_whose_arguments_are_not_an_object_reaches_the_sdk_with_them_as_its_reason():
    app, refused = await pass_through(rpc("estop", ["person in the cell"]))
    [(scope, body)] = app.seen
    assert json.loads(body)["params"] == {"name": "estop", "arguments": {"reason": ["person in the cell"]}}
    assert dict(scope["headers"])[b"content-length"] == str(len(body)).encode()  # the length of what is replayed
    assert refused == []


@pytest.mark.anyio
async def test_a_call_with_malformed_params_is_reported_before_it_is_passed_on():
    app, refused = await pass_through(rpc("gripper_move", [0.04]))
    assert len(app.seen) == 1  # the SDK answers it (-32602)
    assert refused == [("tools/call", {"name": "gripper_move", "arguments": [0.04]}, 7, "invalid_params",
                        "tools/call of gripper_move refused: its arguments are not an object")]


# ------------------------------------------------------------------ an estop that will not run still latches
class Refusing:
    """An app that answers every request with the SDK's 400 error before its tools see it."""

    def __init__(self) -> None:
        self.seen = 0

    async def __call__(self, scope, receive, send) -> None:
        await receive()
        self.seen += 1
        body = json.dumps({"jsonrpc": "2.0", "id": 7, "error": {"code": -32020, "message": "mcp-name header does not "
                                                                 "match"}}).encode()
        await send({"type": "http.response.start", "status": 400, "headers": []})
        await send({"type": "http.response.body", "body": body})


async def refused_through(app: Any, body: bytes) -> tuple[list[tuple], list[RefusedRequest], list[Any]]:
    """`body` through the middleware with latch and refusal recorders; (latches, refusals, what was
    sent), each latch and refusal noting how much of the answer had been sent by then."""
    latches: list[tuple] = []
    refusals: list[RefusedRequest] = []
    sent: list[Any] = []

    def on_estop_refused(reason: Any, principal: Any, why: str) -> int:
        latches.append((reason, principal, why, len(sent)))
        return 4

    async def on_refused(r: RefusedRequest) -> None:
        refusals.append(r)
        assert sent == []  # on record before the answer

    messages = [{"type": "http.request", "body": body, "more_body": False}]

    async def receive() -> Any:
        return messages.pop(0) if messages else {"type": "http.disconnect"}

    async def send(message: Any) -> None:
        sent.append(message)

    middleware = AbandonedMotionStop(app, "/mcp", on_refused=on_refused, on_stop_request=lambda tool, principal: None,
                                     on_estop_refused=on_estop_refused)
    await middleware({"type": "http", "method": "POST", "path": "/mcp", "headers": [SESSION]}, receive, send)
    return latches, refusals, sent


@pytest.mark.anyio
async def test_an_estop_without_a_usable_id_latches_before_it_is_refused():
    app = Recorder(answer=True)
    latches, [refusal], sent = await refused_through(app, rpc("estop", {"reason": "person in the cell"}, request_id=1.0))
    assert [(reason, sent_by_then) for reason, _, _, sent_by_then in latches] == [("person in the cell", 0)]
    assert refusal.outcome == "invalid_request" and refusal.stops == (StopTaken("estop", 4),)
    assert sent[0]["status"] == 400 and app.seen == []


@pytest.mark.anyio
async def test_an_estop_the_sdk_refuses_before_its_tools_latches_before_the_answer_leaves():
    app = Refusing()
    latches, [refusal], sent = await refused_through(app, rpc("estop", {"reason": "r"}))
    [(reason, _, why, sent_by_then)] = latches
    assert reason == "r" and sent_by_then == 0 and "-32020" in why
    assert refusal.outcome == "header_mismatch" and refusal.stops == (StopTaken("estop", 4),)
    assert sent[0]["status"] == 400 and app.seen == 1


@pytest.mark.anyio
async def test_a_stop_motion_the_sdk_refuses_is_recorded_as_held_and_latches_nothing():
    latches, [refusal], _ = await refused_through(Refusing(), rpc("stop_motion", {}))
    assert latches == [] and refusal.stops == (StopTaken("stop_motion"),)


@pytest.mark.anyio
async def test_an_estop_call_the_sdk_refuses_after_dispatch_latches():
    latches: list[tuple] = []
    watch = LatchEstopsNotRun(lambda reason, principal, why: latches.append((reason, why)) or 1)
    ctx = SimpleNamespace(method="tools/call", params={"name": "estop", "arguments": {"reason": "r"}})

    async def refuse(_ctx: Any) -> Any:
        raise ValueError("Invalid or expired requestState")

    with pytest.raises(ValueError):
        await watch(ctx, refuse)  # type: ignore[arg-type]
    assert latches == [("r", "the estop call ended without its tool's answer (ValueError: Invalid or expired "
                             "requestState)")]


@pytest.mark.anyio
@pytest.mark.parametrize("name", ["estop", "stop_motion", "get_safety_status"])
async def test_a_call_answered_after_dispatch_latches_nothing_more(name: str):
    latches: list[tuple] = []
    watch = LatchEstopsNotRun(lambda reason, principal, why: latches.append((reason, why)) or 1)
    ctx = SimpleNamespace(method="tools/call", params={"name": name, "arguments": {}})

    async def answer(_ctx: Any) -> Any:
        return {"content": []}

    assert await watch(ctx, answer) == {"content": []}  # type: ignore[arg-type]
    assert latches == []


@pytest.mark.anyio
async def test_a_batch_is_refused_without_the_app_and_each_stop_tool_in_it_acts_once():
    app = Recorder(answer=True)
    elements = [json.loads(rpc("estop", {"reason": "first"}, request_id=i)) for i in range(3)]
    elements += [json.loads(rpc("stop_motion", request_id=i)) for i in range(3, 1000)]
    elements.append(json.loads(rpc("get_robot_state", request_id=1000)))
    latches, [refusal], sent = await refused_through(app, json.dumps(elements).encode())
    assert [reason for reason, *_ in latches] == ["first"]  # one latch, with the first estop's reason
    assert refusal.stops == (StopTaken("estop", 4), StopTaken("stop_motion"))
    assert refusal.batch is not None and refusal.batch[:4] == ("estop", "estop", "estop", "stop_motion")
    assert len(refusal.batch) == 16 and refusal.outcome == "invalid_request"
    assert sent[0]["status"] == 400 and json.loads(sent[1]["body"])["error"]["code"] == -32600
    assert app.seen == []


@pytest.mark.anyio
async def test_each_stop_tool_in_a_batch_holds_the_robot_once():
    held: list[tuple] = []

    async def ignore(_r: RefusedRequest) -> None:
        pass

    messages = [{"type": "http.request", "body": json.dumps([json.loads(rpc("stop_motion", request_id=i))
                                                              for i in range(500)]).encode(), "more_body": False}]

    async def receive() -> Any:
        return messages.pop(0) if messages else {"type": "http.disconnect"}

    async def send(_message: Any) -> None:
        pass

    middleware = AbandonedMotionStop(Recorder(answer=True), "/mcp", on_refused=ignore,
                                     on_stop_request=lambda tool, principal: held.append((tool, principal)))
    await middleware({"type": "http", "method": "POST", "path": "/mcp", "headers": [SESSION]}, receive, send)
    assert held == [("stop_motion", None)]
