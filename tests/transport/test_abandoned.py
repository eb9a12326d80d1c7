"""`AbandonedMotionStop`: a motion call whose request ends without its response is reported, once,
with its arguments; answered calls, other tools, other paths and oversized bodies are not."""

from __future__ import annotations

import json
from typing import Any

import anyio
import pytest

from armwarden.transport.abandoned import MAX_BODY_BYTES, AbandonedMotionStop, motion_call


def rpc(name: str, arguments: Any = None, method: str = "tools/call") -> bytes:
    return json.dumps({"jsonrpc": "2.0", "id": 7, "method": method,
                       "params": {"name": name, "arguments": arguments if arguments is not None else {}}}).encode()


def run(body: bytes, *, answer: bool, path: str = "/mcp", method: str = "POST", fail: bool = False,
        chunk: int | None = None) -> list[tuple[str, dict]]:
    """Drive the middleware around an app that reads the body and answers (or not)."""
    abandoned: list[tuple[str, dict]] = []

    async def on_abandoned(tool: str, arguments: dict) -> None:
        abandoned.append((tool, arguments))

    async def app(scope, receive, send) -> None:
        more = True
        while more:
            message = await receive()
            more = message.get("more_body", False)
        await send({"type": "http.response.start", "status": 200, "headers": []})
        await send({"type": "http.response.body", "body": b"event: progress", "more_body": True})
        if fail:
            raise RuntimeError("the client went away mid-stream")
        if answer:
            await send({"type": "http.response.body", "body": b"event: result", "more_body": False})

    size = chunk or max(1, len(body))
    pieces = [body[i:i + size] for i in range(0, len(body), size)] or [b""]
    messages = [{"type": "http.request", "body": piece, "more_body": i < len(pieces) - 1} for i, piece in enumerate(pieces)]

    async def receive() -> dict:
        return messages.pop(0) if messages else {"type": "http.disconnect"}

    async def send(message: dict) -> None:
        pass

    middleware = AbandonedMotionStop(app, "/mcp", on_abandoned)

    async def main() -> None:
        try:
            await middleware({"type": "http", "method": method, "path": path}, receive, send)
        except RuntimeError:
            pass

    anyio.run(main)
    return abandoned


@pytest.mark.parametrize("tool", ["execute_plan", "gripper_move", "gripper_grasp", "gripper_home"])
def test_an_unanswered_motion_call_is_reported_with_its_arguments(tool):
    assert run(rpc(tool, {"plan_id": "plan_x"}), answer=False) == [(tool, {"plan_id": "plan_x"})]


def test_a_motion_call_whose_stream_broke_is_reported():
    assert run(rpc("execute_plan", {"plan_id": "p"}), answer=False, fail=True) == [("execute_plan", {"plan_id": "p"})]


def test_a_body_that_arrives_in_pieces_is_put_back_together():
    assert run(rpc("execute_plan", {"plan_id": "p"}), answer=False, chunk=5) == [("execute_plan", {"plan_id": "p"})]


def test_an_answered_motion_call_is_not_reported():
    assert run(rpc("execute_plan", {"plan_id": "p"}), answer=True) == []


@pytest.mark.parametrize("body", [rpc("get_robot_state"), rpc("plan_to_pose"), rpc("execute_plan", method="tools/list"),
                                  b"not json", b"[1, 2]", b""])
def test_other_requests_are_never_reported(body):
    assert run(body, answer=False) == []


def test_other_paths_and_methods_are_passed_through():
    body = rpc("execute_plan", {"plan_id": "p"})
    assert run(body, answer=False, path="/healthz") == []
    assert run(body, answer=False, method="GET") == []


def test_an_oversized_body_is_not_kept():
    padding = "x" * MAX_BODY_BYTES
    assert run(rpc("execute_plan", {"plan_id": "p", "pad": padding}), answer=False, chunk=4096) == []


def test_non_object_arguments_become_an_empty_mapping():
    assert motion_call(rpc("execute_plan", ["plan_x"])) == ("execute_plan", {})
