"""The Guard and the flows it runs: `door` (the Guard: the execution slot, the pipeline order),
`gates` (the state the flows share and the gates they run over it), `planning`, `execution`,
`gripper`, `actions`, `stopping`, `readings`."""

from armwarden.approval.decision import Approval, Prompt
from armwarden.guard.door import Guard, refuse
from armwarden.guard.planning import Previewer
from armwarden.guard.readings import MAX_STATE_AGE_S

__all__ = ["MAX_STATE_AGE_S", "Approval", "Guard", "Previewer", "Prompt", "refuse"]
