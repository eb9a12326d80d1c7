"""`armwarden serve --console-port PORT` over stdio ends cleanly when the client closes stdin:
exit 0, a shutdown record, and nothing on stderr that looks like a crash (issue 31, item 7:
a `CancelledError` traceback from the console's server was logged at every such exit)."""

from __future__ import annotations

import http.client
import subprocess
import time
from pathlib import Path

from tests.helpers import CLI, REPO, child_env, free_port, records_of, stop_process


def console_answers(port: int) -> bool:
    """Whether the console's HTTP server answers a request at all (any status)."""
    connection = http.client.HTTPConnection("127.0.0.1", port, timeout=5)
    try:
        connection.request("GET", "/console/")
        connection.getresponse().read()
        return True
    except OSError:
        return False
    finally:
        connection.close()


def test_end_of_stdin_with_the_console_on_exits_0_without_a_traceback(tmp_path: Path) -> None:
    audit, stderr_path, port = tmp_path / "audit.jsonl", tmp_path / "stderr.log", free_port()
    config = tmp_path / "fake.yaml"
    config.write_text("speedup: 20\n", encoding="utf-8")
    with open(stderr_path, "wb") as stderr:
        process = subprocess.Popen(
            [*CLI, "serve", "--console-port", str(port), "--audit-log", str(audit), "--backend-config", str(config)],
            cwd=REPO, env=child_env(), stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=stderr)
    try:
        deadline = time.monotonic() + 60
        while not console_answers(port):  # the console's server is up, with its lifespan task running
            assert process.poll() is None, stderr_path.read_text(encoding="utf-8")
            assert time.monotonic() < deadline, "the console never answered"
            time.sleep(0.05)
        assert process.stdin is not None
        process.stdin.close()
        code = process.wait(timeout=60)
    finally:
        stop_process(process, 10)
    log = stderr_path.read_text(encoding="utf-8")
    assert code == 0, log
    assert "Traceback" not in log and "CancelledError" not in log and " ERROR " not in log, log
    last = records_of(audit)[-1]
    assert last["event"] == "shutdown" and last["detail"] == "end of stdin"
