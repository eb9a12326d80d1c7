#!/usr/bin/env python3
"""Run a command under strace and fail if any process of it sends to an address off this host.

DDS must stay on loopback in tests (localhost-only discovery, random domain). Binding a socket to
0.0.0.0 or to a LAN address is not sending; what matters is where datagrams and connections go,
so every ``sendto``/``sendmsg``/``sendmmsg``/``connect`` with an IP destination is checked
against 127.0.0.0/8 and ::1. Shared-memory transport traffic never touches a socket.

    python scripts/check_loopback.py -- .venv/bin/python -m pytest -q tests_ros

Needs strace (and permission to ptrace the children). Exit 0: only loopback; 1: a destination
off this host (listed); 2: strace missing or the command failed.
"""

from __future__ import annotations

import ipaddress
import re
import shutil
import subprocess
import sys
import tempfile
from collections import Counter
from pathlib import Path

_CALL = re.compile(r"\b(sendto|sendmsg|sendmmsg|connect)\(")
_IPV4 = re.compile(r'inet_addr\("([0-9.]+)"\)')
_IPV6 = re.compile(r'inet_pton\(AF_INET6,\s*"([0-9a-fA-F:.]+)"')


def destinations(trace: str) -> Counter[str]:
    """IP destinations of send/connect calls in an strace log, with counts."""
    found: Counter[str] = Counter()
    for line in trace.splitlines():
        if _CALL.search(line) is None:
            continue
        for address in (*_IPV4.findall(line), *_IPV6.findall(line)):
            found[address] += 1
    return found


def main(argv: list[str]) -> int:
    if argv and argv[0] == "--":
        argv = argv[1:]
    if not argv:
        print(__doc__, file=sys.stderr)
        return 2
    if shutil.which("strace") is None:
        print("strace not found", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        log = Path(tmp) / "strace.log"
        command = ["strace", "-f", "--seccomp-bpf", "-qq", "-e", "trace=sendto,sendmsg,sendmmsg,connect", "-o", str(log), *argv]
        returncode = subprocess.run(command).returncode
        found = destinations(log.read_text())
    off_host = {address: count for address, count in found.items() if not ipaddress.ip_address(address).is_loopback}
    print(f"IP send/connect destinations: {dict(found)}", file=sys.stderr)
    if off_host:
        print(f"OFF-HOST destinations: {off_host}", file=sys.stderr)
        return 1
    if returncode != 0:
        print(f"the command failed (exit {returncode}); no off-host destination seen", file=sys.stderr)
        return 2
    print("only loopback destinations", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
