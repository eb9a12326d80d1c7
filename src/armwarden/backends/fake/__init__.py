"""The fake backend: a kinematic arm and a parallel gripper, deterministic, no dependency beyond the core.

The package is the module backends/__init__.py's table names for "fake": it exposes `Config` (the
`--backend-config` schema) and `create_backend`. The parts: `backend` (`FakeBackend`, the
composition), `config`, `arm`, `gripper`, `cameras`, `controllers`, and `testing` (how the test
harness builds it, with its fault-injection attributes).
"""

from armwarden.backends.fake.backend import create_backend
from armwarden.backends.fake.config import Config

__all__ = ["Config", "create_backend"]
