"""What the benchmark sections share (scripts/bench.py and scripts/_bench/): percentile summaries,
timed tool calls, the benchmark's policy and an operator who approves everything."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from armwarden.evaluation.daemon_process import stop_process as stop_process  # re-exported: one stop for every child process

#: rate limits of the benchmark's policy: it calls far faster than an agent would
RAISED_RATE_LIMITS = {
    f"rate_limits.{key}": 100000
    for key in ("global_per_minute", "default_per_minute", "per_tool.plan_to_pose", "per_tool.plan_to_joints",
                "per_tool.execute_plan", "per_tool.camera_snapshot", "per_tool.reset_estop")
}


def percentiles(values: list[float], quantiles: tuple[int, ...] = (50, 95)) -> dict[str, float]:
    """{"n", "p<q>" for each quantile, "max"}; NaN figures when there are no values."""
    if not values:
        return {"n": 0, **{f"p{q}": float("nan") for q in quantiles}, "max": float("nan")}
    array = np.asarray(values, dtype=float)
    return {"n": len(values), **{f"p{q}": float(np.percentile(array, q)) for q in quantiles}, "max": float(array.max())}


def median_p95(values_s: list[float]) -> dict[str, float]:
    """{"median_ms", "p95_ms", "n"} of durations given in seconds."""
    ms = [v * 1e3 for v in values_s]
    return {"median_ms": statistics.median(ms), "p95_ms": float(np.percentile(np.asarray(ms), 95)), "n": len(ms)}


async def timed_calls(client: Any, tool: str, args_for: Callable[[int], dict[str, Any]], count: int, *,
                      warm: int) -> list[float]:
    """`count` calls of `tool` (arguments `args_for(i)`), each one's round trip [s], without the
    first `warm` (they warm caches up); a call that fails stops the benchmark."""
    out = []
    for i in range(count):
        start = time.perf_counter()
        result = await client.call_tool(tool, args_for(i))
        out.append(time.perf_counter() - start)
        if result.is_error:
            raise RuntimeError(f"{tool} failed in the benchmark: {result.content[0].text}")
    return out[warm:]


async def timed_ms(client: Any, tool: str, arguments: dict[str, Any]) -> float:
    """One call's round trip [ms]; a call that fails stops the benchmark."""
    return (await timed_calls(client, tool, lambda i: arguments, 1, warm=0))[0] * 1e3


def bench_policy(**overrides: Any) -> Any:
    """The bundled FR3 policy with `RAISED_RATE_LIMITS`, then `overrides` (dotted paths)."""
    import yaml

    from armwarden.policy import apply_overrides, bundled_policy, parse_policy

    document = yaml.safe_load(bundled_policy("fr3").read_text())
    return parse_policy(apply_overrides(document, RAISED_RATE_LIMITS | overrides), source="bench")


async def approve_all(context: Any, params: Any) -> Any:
    """The benchmark's operator: accepts every approval prompt."""
    import mcp_types as types

    return types.ElicitResult(action="accept", content={"approve": True, "operator": "bench"})


def timed_estop_post(port: int, token: str, reason: str, timeout_s: float = 2.0) -> dict[str, Any]:
    """One ``POST /estop`` to the stop channel on 127.0.0.1:`port` (the request `send_estop`
    makes), stamped at each step on `time.monotonic` — CLOCK_MONOTONIC, which every process of
    the host shares, so a daemon's own stamps line up with these: "start", "connected", "sent",
    "answered" (status line and headers read), "done" [s]; plus the channel's "event" and
    "stop_issued_ms". Raises RuntimeError saying what happened when the stop was not confirmed."""
    import http.client
    import json

    body = json.dumps({"reason": reason}).encode()
    headers = {"Authorization": f"Bearer {token}", "Content-Type": "application/json", "Connection": "close"}
    connection = http.client.HTTPConnection("127.0.0.1", port, timeout=timeout_s)
    start = time.monotonic()
    try:
        connection.connect()
        connected = time.monotonic()
        connection.request("POST", "/estop", body=body, headers=headers)  # one send: head and body together
        sent = time.monotonic()
        response = connection.getresponse()
        answered = time.monotonic()
        answer = json.loads(response.read(65536))
        done = time.monotonic()
    except (OSError, http.client.HTTPException, ValueError) as exc:
        raise RuntimeError(f"{type(exc).__name__}: {exc} after {(time.monotonic() - start) * 1e3:.0f} ms") from exc
    finally:
        connection.close()
    if response.status != 200 or not isinstance(answer, dict) or answer.get("estopped") is not True:
        raise RuntimeError(f"answered {response.status}: {answer}")
    return {"event": int(answer["event"]), "stop_issued_ms": answer.get("stop_issued_ms"), "start": start,
            "connected": connected, "sent": sent, "answered": answered, "done": done}
