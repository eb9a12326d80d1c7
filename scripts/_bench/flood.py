#!/usr/bin/env python3
"""The load generator of `scripts/bench.py flood`: a bounded loopback flood on one ArmWarden daemon.

Runs as its own process (one asyncio loop) so that the process measuring e-stops is not starved
by it; on a 2-core machine it still competes with the daemon for CPU, which is part of the load.

- MCP clients (official SDK, streamable HTTP, one operator token), each in its own task:
  planners (plan_to_pose and plan_to_joints in turn, half of them with the PNG preview), readers
  (get_robot_state), cameras (camera_snapshot), movers (plan a 0.05 rad move of joint 1 from the
  current state and execute it) and session churners (open a NEW session, call get_robot_state,
  close it).
- Slow connections to the MCP port and to the stop-channel port: half send nothing after
  connecting (half-open), half send a request head one byte every `--trickle` seconds
  (slowloris). One the server closes is reopened after a short pause.

Everything is on 127.0.0.1 and bounded in time (`--ramp` + `--duration`) and in count. The
process prints ``ready`` on stdout once every slow connection was opened and every client has
made its first call; calls are counted from then on, for `--duration` seconds, or until SIGTERM
ends the window early. The figures go to `--out` (JSON) at the end.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import signal
import statistics
import sys
import time
from collections import Counter
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx2
from mcp import Client
from mcp.client.streamable_http import streamable_http_client

HOST = "127.0.0.1"  # never anything else
CALL_TIMEOUT_S = 30.0
MAX_CALLS_PER_CLIENT = 1_000_000  # a bound on top of the time limit
MAX_RECONNECTS_PER_SLOW_SOCKET = 10_000


@dataclass
class Stats:
    """What the flood achieved inside the counted window (`counting` True)."""

    counting: bool = False
    ok: Counter[str] = field(default_factory=Counter)  # successful results, by tool / kind
    refused: Counter[str] = field(default_factory=Counter)  # isError results (e.g. motion while e-stopped)
    failed: Counter[str] = field(default_factory=Counter)  # exceptions (timeouts, transport errors)
    outcomes: Counter[str] = field(default_factory=Counter)  # execute_plan statuses
    reasons: Counter[str] = field(default_factory=Counter)  # "tool: start of the refusal text"
    slow_open: Counter[str] = field(default_factory=Counter)  # currently open slow sockets, by port name
    slow_opened: Counter[str] = field(default_factory=Counter)  # connections made (inside the window)
    slow_closed_by_server: Counter[str] = field(default_factory=Counter)
    slow_connect_errors: Counter[str] = field(default_factory=Counter)
    held_samples: dict[str, list[int]] = field(default_factory=dict)

    def count(self, bucket: Counter[str], key: str) -> None:
        if self.counting:
            bucket[key] += 1


class Flood:
    def __init__(self, args: argparse.Namespace) -> None:
        self.args = args
        self.url = f"http://{HOST}:{args.mcp_port}/mcp"
        self.stats = Stats()
        self.end = float("inf")  # monotonic end of the run, set once ramped up
        self.ended = False  # SIGTERM: end now
        self.started_clients = 0
        self.first_call = asyncio.Event()

    def running(self) -> bool:
        return not self.ended and time.monotonic() < self.end

    def sdk_client(self, mode: str = "auto") -> tuple[httpx2.AsyncClient, Client]:
        http = httpx2.AsyncClient(headers={"Authorization": f"Bearer {self.args.token}"}, timeout=CALL_TIMEOUT_S)
        return http, Client(streamable_http_client(self.url, http_client=http), mode=mode)

    async def call(self, session: Client, tool: str, arguments: dict[str, Any], kind: str | None = None) -> Any:
        """One tool call, counted; returns the structured result, or None when refused or failed."""
        label = kind or tool
        try:
            result = await asyncio.wait_for(session.call_tool(tool, arguments), CALL_TIMEOUT_S)
        except (Exception, asyncio.TimeoutError):
            self.stats.count(self.stats.failed, label)
            return None
        if result.is_error:
            self.stats.count(self.stats.refused, label)
            text = getattr(result.content[0], "text", "") if result.content else ""
            self.stats.count(self.stats.reasons, f"{tool}: {text[:60]}")
            return None
        self.stats.count(self.stats.ok, label)
        return result.structured_content

    # ------------------------------------------------------------------------------ MCP clients
    async def persistent(self, body: Callable[[Client, int], Awaitable[None]]) -> None:
        """An already open session calling `body` in a loop; reopened if the transport fails."""
        first = True
        for _ in range(100):  # reopen bound
            if not self.running():
                return
            http, client = self.sdk_client()
            try:
                async with http, client as session:
                    for i in range(MAX_CALLS_PER_CLIENT):
                        if not self.running():
                            return
                        await body(session, i)
                        if first:
                            first = False
                            self.mark_started()
            except Exception:
                self.stats.count(self.stats.failed, "session")
                await asyncio.sleep(0.2)

    def mark_started(self) -> None:
        self.started_clients += 1
        if self.started_clients >= self.args.clients:
            self.first_call.set()

    async def planner(self, session: Client, i: int) -> None:
        preview = (i // 2) % 2 == 0  # half of each kind with the PNG preview (the tools' default)
        if i % 2:
            target = {"x": 0.40 + 0.02 * (i % 3), "y": 0.05 - 0.02 * (i % 2), "z": 0.35}
            await self.call(session, "plan_to_pose", {"position": target, "preview": preview})
        else:
            goal = list(self.args.home)
            goal[1] += 0.05 * ((i // 2) % 3 - 1)
            await self.call(session, "plan_to_joints", {"joint_positions": goal, "preview": preview})

    async def reader(self, session: Client, i: int) -> None:
        await self.call(session, "get_robot_state", {})

    async def camera(self, session: Client, i: int) -> None:
        await self.call(session, "camera_snapshot", {"camera": ("wrist", "scene")[i % 2]})

    async def mover(self, session: Client, i: int) -> None:
        state = await self.call(session, "get_robot_state", {})
        if state is None:
            await asyncio.sleep(0.05)
            return
        goal = list(state["joint_positions"])
        goal[0] += -0.05 if goal[0] > self.args.home[0] else 0.05  # stay near home
        plan = await self.call(session, "plan_to_joints", {"joint_positions": goal, "preview": False})
        if plan is None or plan.get("status") != "ok":
            await asyncio.sleep(0.05)
            return
        report = await self.call(session, "execute_plan", {"plan_id": plan["plan_id"]})
        if report is None:
            await asyncio.sleep(0.05)  # refused (e.g. e-stopped, another motion running): do not spin
        else:
            self.stats.count(self.stats.outcomes, str(report.get("status")))

    async def churner(self) -> None:
        """A NEW session (initialize handshake) for every call."""
        first = True
        for _ in range(MAX_CALLS_PER_CLIENT):
            if not self.running():
                return
            http, client = self.sdk_client(mode="legacy")
            try:
                async with http, client as session:
                    self.stats.count(self.stats.ok, "new_session")
                    await self.call(session, "get_robot_state", {}, kind="get_robot_state (new session)")
            except Exception:
                self.stats.count(self.stats.failed, "new_session")
                await asyncio.sleep(0.05)
            if first:
                first = False
                self.mark_started()

    # ------------------------------------------------------------------------------ slow sockets
    async def slow_socket(self, port: int, name: str, trickle: bool, head: bytes) -> None:
        for _ in range(MAX_RECONNECTS_PER_SLOW_SOCKET):
            if not self.running():
                return
            try:
                reader, writer = await asyncio.wait_for(asyncio.open_connection(HOST, port), 5.0)
            except (OSError, asyncio.TimeoutError):
                self.stats.count(self.stats.slow_connect_errors, name)
                await asyncio.sleep(0.25)
                continue
            self.stats.slow_open[name] += 1
            self.stats.count(self.stats.slow_opened, name)
            sent = 0
            try:
                while self.running():
                    try:
                        data = await asyncio.wait_for(reader.read(4096), self.args.trickle)
                    except asyncio.TimeoutError:
                        if trickle and sent < len(head):  # one more byte of a request that never ends
                            writer.write(head[sent : sent + 1])
                            sent += 1
                            await writer.drain()
                        continue
                    if not data:  # the server closed it: count and reopen
                        self.stats.count(self.stats.slow_closed_by_server, name)
                        break
            except OSError:
                self.stats.count(self.stats.slow_closed_by_server, name)
            finally:
                self.stats.slow_open[name] -= 1
                writer.close()
            await asyncio.sleep(0.25)

    async def sample_held(self) -> None:
        while self.running():
            if self.stats.counting:
                for name in ("mcp", "stop_channel"):
                    self.stats.held_samples.setdefault(name, []).append(self.stats.slow_open[name])
            await asyncio.sleep(0.25)

    # ------------------------------------------------------------------------------ the run
    async def run(self) -> dict[str, Any]:
        a = self.args
        asyncio.get_running_loop().add_signal_handler(signal.SIGTERM, lambda: setattr(self, "ended", True))
        ramp_start = time.monotonic()
        self.end = ramp_start + a.ramp + a.duration  # provisional bound for the ramp-up
        mcp_head = (f"POST /mcp HTTP/1.1\r\nHost: {HOST}:{a.mcp_port}\r\nAuthorization: Bearer x\r\n"
                    "X-Slow: " + "z" * 4000).encode()
        channel_head = (f"POST /estop HTTP/1.1\r\nHost: {HOST}:{a.estop_port}\r\nX-Slow: " + "z" * 4000).encode()
        tasks = []
        for i in range(a.slow_mcp):
            tasks.append(asyncio.create_task(self.slow_socket(a.mcp_port, "mcp", i % 2 == 1, mcp_head)))
        for i in range(a.slow_channel):
            tasks.append(asyncio.create_task(self.slow_socket(a.estop_port, "stop_channel", i % 2 == 1, channel_head)))
        kinds = {"planner": self.planner, "reader": self.reader, "camera": self.camera, "mover": self.mover}
        mix: dict[str, int] = dict(zip(("planner", "reader", "camera", "mover", "churner"), a.mix, strict=True))
        for kind, n in mix.items():
            for _ in range(n):
                if kind == "churner":
                    tasks.append(asyncio.create_task(self.churner()))
                else:
                    tasks.append(asyncio.create_task(self.persistent(kinds[kind])))
        tasks.append(asyncio.create_task(self.sample_held()))
        with contextlib.suppress(asyncio.TimeoutError):  # then count anyway; `clients_started` says how many were up
            await asyncio.wait_for(self.first_call.wait(), a.ramp)
        self.stats.counting = True
        window_start = time.monotonic()
        ramp_s = window_start - ramp_start
        self.end = window_start + a.duration
        print(f"ready {a.duration}", flush=True)
        await asyncio.gather(*tasks, return_exceptions=True)
        window_s = time.monotonic() - window_start
        return self.report(window_s, ramp_s, mix)

    def report(self, window_s: float, ramp_s: float, mix: dict[str, int]) -> dict[str, Any]:
        s = self.stats
        held = {name: {"min": min(v), "median": statistics.median(v), "max": max(v)} for name, v in s.held_samples.items() if v}
        return {
            "window_s": window_s,
            "ramp_s": ramp_s,
            "clients": self.args.clients,
            "clients_started": self.started_clients,
            "mix": mix,
            "ok": dict(s.ok),
            "refused": dict(s.refused),
            "failed": dict(s.failed),
            "execute_outcomes": dict(s.outcomes),
            "refusal_reasons": dict(s.reasons.most_common(8)),
            "calls_per_s": {k: (s.ok[k] + s.refused[k]) / window_s for k in sorted(set(s.ok) | set(s.refused))},
            "slow_target": {"mcp": self.args.slow_mcp, "stop_channel": self.args.slow_channel},
            "slow_held": held,
            "slow_opened": dict(s.slow_opened),
            "slow_closed_by_server": dict(s.slow_closed_by_server),
            "slow_connect_errors": dict(s.slow_connect_errors),
        }


def parse(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--mcp-port", type=int, required=True)
    parser.add_argument("--estop-port", type=int, required=True)
    parser.add_argument("--token-file", required=True, help="file holding just an operator bearer token")
    parser.add_argument("--home", type=float, nargs=7, required=True, help="the arm's joint positions at start")
    parser.add_argument("--duration", type=float, default=30.0, help="counted window [s] after the ramp-up")
    parser.add_argument("--ramp", type=float, default=20.0, help="at most this long [s] to open everything")
    parser.add_argument("--mix", type=int, nargs=5, default=[8, 8, 4, 2, 10], metavar="N",
                        help="planners readers cameras movers churners")
    parser.add_argument("--slow-mcp", type=int, default=200, help="slow connections to the MCP port")
    parser.add_argument("--slow-channel", type=int, default=100, help="slow connections to the stop-channel port")
    parser.add_argument("--trickle", type=float, default=2.0, help="seconds between two bytes of a slowloris head")
    parser.add_argument("--out", required=True, help="write the figures here (JSON)")
    args = parser.parse_args(argv)
    args.token = Path(args.token_file).read_text(encoding="utf-8").strip()  # not on the command line: `ps` shows that
    args.clients = sum(args.mix)
    if not (0 < args.duration <= 600 and 0 < args.ramp <= 120 and args.slow_mcp + args.slow_channel <= 2000):
        parser.error("duration (0, 600] s, ramp (0, 120] s and at most 2000 slow connections")
    return args


def main() -> int:
    import logging

    logging.basicConfig(level=logging.ERROR)  # the SDK and HTTP client log every request otherwise
    args = parse()
    figures = asyncio.run(Flood(args).run())
    Path(args.out).write_text(json.dumps(figures, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
