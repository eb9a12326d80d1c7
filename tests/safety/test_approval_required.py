"""`approval_required`: which actions need a human under each `approval.mode`.

Releasing an e-stop is the one action no policy can wave through: the policy loader adds
`reset_estop` to `require_for`, and `approval_required` answers True for it before it looks at
the mode at all, so a policy with `mode: never` still asks a human to release an e-stop.
"""

from __future__ import annotations

import pytest

from armwarden.approval.decision import approval_required
from tests.server.harness import policy_with

OTHER_ACTIONS = ("execute", "switch_controllers", "error_recovery", "set_collision_thresholds")


def test_under_mode_never_a_reset_still_needs_a_human() -> None:
    policy = policy_with(**{"approval.mode": "never"})
    assert approval_required(policy, "reset_estop")


@pytest.mark.parametrize("action", OTHER_ACTIONS)
def test_under_mode_never_every_other_action_runs_without_asking(action) -> None:
    policy = policy_with(**{"approval.mode": "never"})
    assert not approval_required(policy, action, has_soft_violations=True)


@pytest.mark.parametrize("action", OTHER_ACTIONS)
def test_under_mode_always_every_action_asks(action) -> None:
    policy = policy_with(**{"approval.mode": "always"})
    assert approval_required(policy, action, has_soft_violations=False)


def test_outside_envelope_asks_for_a_plan_only_when_it_has_soft_violations() -> None:
    policy = policy_with(**{"approval.mode": "outside_envelope"})
    assert approval_required(policy, "execute", has_soft_violations=True)
    assert not approval_required(policy, "execute", has_soft_violations=False)
