"""The MuJoCo backend (work in progress): real physics behind the backend contract.

Built so far: `model` (the MuJoCo model built from the same robot description as the Pinocchio
model, with the envelope's capsules as collision geometry) and `backend` (`MujocoBackend`, its
`Config` and `create_backend`: physics on the servo thread, measured state, stops, the wrench,
the gripper, offscreen cameras). The registry still lists "mujoco" as planned until it passes
the whole backend contract and the scenario suite.

Importing this package chooses MuJoCo's offscreen OpenGL platform when the user has not:
`MUJOCO_GL=egl` (Mesa's EGL renders on CPU-only, headless machines). MuJoCo reads it once, when
`mujoco` is first imported, so this package must be imported before `mujoco` is.
"""

import os

os.environ.setdefault("MUJOCO_GL", "egl")
