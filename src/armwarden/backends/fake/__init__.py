"""The fake backend: a kinematic arm and a parallel gripper, deterministic, no dependency beyond the core.

The package is the module backends/__init__.py's table names for "fake": it exposes `Config` (the
`--backend-config` schema) and `create_backend`. The modules: `backend` (`FakeBackend`, the arm
and the cell it builds), `config`, `arm`, the cell's parts in `gripper`, `cameras`, `controllers`
and `contact` (wrench, collision thresholds, error recovery), `knobs` (the fault injections and
records the parts share), and `testing` (how the test harness builds it).
"""

from armwarden.backends.fake.backend import create_backend
from armwarden.backends.fake.config import Config

__all__ = ["Config", "create_backend"]
