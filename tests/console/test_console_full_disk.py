"""The operator console on a full audit disk (issue 24, item 2): a console opened before the disk
filled must not show a release that did not happen, must show that the log is unusable, and its
reset must leave the e-stop latched and say so."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.console.served import csrf_of, served_console, sign_in
from tests.fulldisk import SmallDisk
from tests.helpers import records_of

pytestmark = pytest.mark.anyio


async def test_a_console_reset_on_a_full_audit_disk_leaves_the_estop_latched_and_shows_the_log_unusable(
        tmp_path: Path) -> None:
    disk = SmallDisk()
    async with served_console(tmp_path, audit_disk=disk) as served, served.browser_client() as http:
        await sign_in(http, served.operator_token)
        event = await served.harness.guard.emergency_stop("checking the cell", source="estop")
        page = await http.get("/console/safety")  # the page the operator has open
        disk.fill()
        reset = await http.post("/console/reset", data={"event": str(event.estop_event.number), "csrf": csrf_of(page.text)})
        shown = await http.get(reset.headers["location"].removeprefix(served.base))
        state = (await http.get("/console/api/state")).json()
        fragment = await http.get("/console/fragment/safety")

    assert reset.status_code == 303
    assert '<p class="message error" id="message">Release refused: the audit log cannot record it' in shown.text
    assert served.harness.guard.latch.is_latched
    assert state["safety"]["estopped"] is True
    assert state["safety"]["audit_ok"] is False and "No space left on device" in state["safety"]["audit_error"]
    assert 'id="audit-unusable"' in fragment.text and "E-STOP LATCHED" in fragment.text
    assert [r for r in records_of(served.harness.audit_path) if r["event"] in ("estop_release", "console_reset_estop")] == []
