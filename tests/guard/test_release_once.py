"""Two releases of one e-stop at the same moment (two console operators, or a console and an MCP
`reset_estop`): one takes effect, the other is refused before it writes anything, so the log holds
exactly one `estop_release` record per release that happened.

Found by an outside review (issue 24, review 1, item 5): both wrote an `estop_release ...
releasing` record before either took effect, and only one released.
"""

from __future__ import annotations

import asyncio

import pytest

from armwarden.core.errors import RefusalCode, SafetyRefusal
from tests.helpers import records_of
from tests.server.harness import arm_harness

pytestmark = pytest.mark.anyio


async def test_two_concurrent_releases_of_one_estop_leave_one_release_record(tmp_path) -> None:
    async with arm_harness(tmp_path) as arm:
        event = (await arm.guard.emergency_stop("hand in the cell")).estop_event

        outcomes = await asyncio.gather(arm.guard.reset_estop_typed(str(event.number), operator="first"),
                                        arm.guard.reset_estop_typed(str(event.number), operator="second"),
                                        return_exceptions=True)

        assert not arm.guard.latch.is_latched
    refusals = [o for o in outcomes if isinstance(o, SafetyRefusal)]
    assert len(refusals) == 1 and refusals[0].code is RefusalCode.RESET_REFUSED
    assert "not latched" in str(refusals[0])
    releases = [r for r in records_of(arm.audit_path) if r["event"] == "estop_release"]
    assert [r["operator"] for r in releases] == ["first"]  # the one that took effect
