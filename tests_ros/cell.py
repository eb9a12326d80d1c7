"""The fake FR3 cell, for the tests: it lives in `armwarden.backends.ros2.fake_cell` (the
evaluation starts it too, and product code cannot import tests). ``python -m tests_ros.cell``
still runs it standalone."""

from __future__ import annotations

import sys

from armwarden.backends.ros2.fake_cell import (
    CAMERA_PERIOD_S,
    GRIPPER_GOAL,
    GRIPPER_SPEED_MPS,
    READY,
    STATE_PERIOD_S,
    Cell,
    CellConfig,
    CellJournal,
    Counters,
    GoalMode,
    _acceleration,
    _sample,
    main,
)

__all__ = ["CAMERA_PERIOD_S", "GRIPPER_GOAL", "GRIPPER_SPEED_MPS", "READY", "STATE_PERIOD_S", "Cell", "CellConfig",
           "CellJournal", "Counters", "GoalMode", "_acceleration", "_sample", "main"]

if __name__ == "__main__":
    sys.exit(main())
