"""The MuJoCo backend: real physics behind the backend contract (`--backend mujoco`).

`model` builds the cell from the same robot description as the Pinocchio model, with the
envelope's capsules as collision geometry (its parts: `scene`, `gains`, `gripper_model`, `names`);
`config` is its strict `Config`; `backend` is `MujocoBackend` and `create_backend`, composing the
arm (`arm`: physics on the servo thread, braking stops), the fingers (`gripper`) and the offscreen
cameras (`cameras`). See docs/backends/mujoco.md.

Importing this package chooses MuJoCo's offscreen OpenGL platform when the user has not:
`MUJOCO_GL=egl` (Mesa's EGL renders on CPU-only, headless machines). MuJoCo reads it once, when
`mujoco` is first imported, so this package must be imported before `mujoco` is.
"""

import os

os.environ.setdefault("MUJOCO_GL", "egl")
