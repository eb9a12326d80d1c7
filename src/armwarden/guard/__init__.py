"""The Guard and the flows it runs: `door` (the Guard: its gates, the execution slot, the
pipeline order), `planning`, `execution`, `gripper`, `actions`, `stopping`, `readings`."""

from armwarden.approval.decision import Approval, Prompt
from armwarden.guard.door import Guard, refuse
from armwarden.guard.planning import PlanKind, Previewer
from armwarden.guard.readings import MAX_STATE_AGE_S

__all__ = ["MAX_STATE_AGE_S", "Approval", "Guard", "PlanKind", "Previewer", "Prompt", "refuse"]
