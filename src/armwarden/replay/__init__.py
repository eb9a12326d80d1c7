"""Audit replay: what would another policy have done on the sessions this log recorded?

Every `plan_*` call's audit record carries what an offline replay needs (`extra.replay`, written
by `armwarden.guard.planning.replay_facts`): the start joint state the Guard planned from, the
request as the planner received it, the digest of the policy in force and the planner settings.
`armwarden audit replay LOG --policy CANDIDATE.yaml` verifies the chain (`records`), plans every
recorded request again from its start state under the candidate policy with the daemon's own
planners, detour search, envelope and verdict (`engine`, through `plan_offline`: no backend, no
server, nothing moves), and reports per plan the original outcome against the candidate's, the
executed motions the candidate would have rejected first (`report` holds the data and its JSON,
`markdown` renders it).

Deterministic: the same log and policy give a byte-identical report. Planning is deterministic for
the same request, start state and policy; the detour search (OMPL) is seeded from the request and
the start state, so it repeats exactly whenever it ends within the policy's
`motion.planning_time_s` (outcomes it decided are marked in the report). Records written before
the replay data existed are listed as not replayable, with the reason.
"""

from armwarden.replay.cli import replay_command, replay_log
from armwarden.replay.engine import replan
from armwarden.replay.markdown import render_markdown
from armwarden.replay.records import BrokenLog, Execution, Outcome, PlanCall, TrustedLog, read_trusted
from armwarden.replay.report import PlanRow, PolicyRef, ReplayReport, change_of

__all__ = [
    "BrokenLog",
    "Execution",
    "Outcome",
    "PlanCall",
    "PlanRow",
    "PolicyRef",
    "ReplayReport",
    "TrustedLog",
    "change_of",
    "read_trusted",
    "render_markdown",
    "replan",
    "replay_command",
    "replay_log",
]
