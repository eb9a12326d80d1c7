"""On stdio, stdout is the MCP channel from the daemon's first instruction to its last: a native
library of a backend that writes to fd 1 as the backend opens or closes (Fast DDS did, when it
could not create its shared memory) writes to stderr, never onto the client's wire."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from tests.helpers import REPO, child_env

#: a daemon whose backend, as it opens and as it closes, writes to fd 1 as a native library would
NOISY_DAEMON = """
import os, sys
from armwarden.daemon import serve

opened, closed = serve.open_assembly, serve.close_assembly

async def open_noisily(parts):
    os.write(1, b"native library noise as the backend opens\\n")
    return await opened(parts)

async def close_noisily(assembly, why):
    os.write(1, b"native library noise as the backend closes\\n")
    return await closed(assembly, why)

serve.open_assembly, serve.close_assembly = open_noisily, close_noisily
from armwarden.cli import main
sys.exit(main(sys.argv[1:]))
"""

INITIALIZE = {"jsonrpc": "2.0", "id": 1, "method": "initialize",
              "params": {"protocolVersion": "2025-06-18", "capabilities": {},
                         "clientInfo": {"name": "test", "version": "0"}}}


def test_a_backend_writing_to_fd_1_as_it_opens_and_closes_leaves_the_wire_pure_json_rpc(tmp_path: Path) -> None:
    result = subprocess.run(
        [sys.executable, "-c", NOISY_DAEMON, "serve", "--audit-log", str(tmp_path / "audit.jsonl")],
        input=(json.dumps(INITIALIZE) + "\n").encode(), capture_output=True, cwd=REPO, env=child_env(),
        timeout=120,  # a bound on a hung test, not a timing threshold
    )
    stdout, stderr = result.stdout.decode(), result.stderr.decode()
    assert result.returncode == 0, stderr
    lines = stdout.splitlines()
    assert lines and all(json.loads(line)["jsonrpc"] == "2.0" for line in lines), stdout
    assert json.loads(lines[0])["id"] == 1 and "result" in json.loads(lines[0])
    assert "noise as the backend opens" in stderr and "noise as the backend closes" in stderr
