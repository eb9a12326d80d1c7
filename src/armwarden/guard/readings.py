"""What the tools may read from the robot: joint state, TCP pose, wrench, frames, controllers,
the ROS graph, camera images. Reads only: nothing here commands the backend.

The Guard owns one `Readings` and answers the introspection tools through it; its own checks use
`joint_state` (fresh and finite, or a refusal) and `backend_call` (a backend failure becomes a
BACKEND_ERROR refusal) too.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from typing import Any

import anyio
import numpy as np

from armwarden import conversions
from armwarden.backends.base import Backend
from armwarden.core.errors import BackendError, RefusalCode, SafetyRefusal, StoppedBeforeStart
from armwarden.core.state import JointState
from armwarden.policy import Policy
from armwarden.results import (
    ControllerList,
    ControllerModel,
    EnvelopeModel,
    GraphModel,
    PoseModel,
    Quaternion,
    RobotState,
    TransformResult,
)
from armwarden.robot.model import Pose, RobotModel
from armwarden.safety import checks
from armwarden.safety.estop import flatten_reason

#: how stale a joint state may be before planning/execution refuses it [s]
MAX_STATE_AGE_S = 0.5


class Readings:
    """Backend and model reads, each refused (never guessed) when the data is missing or stale."""

    def __init__(self, policy: Policy, robot: RobotModel, backend: Backend, clock: Callable[[], float]) -> None:
        self.policy = policy
        self.robot = robot  # the loop-side model (planning has its own)
        self.backend = backend
        self._clock = clock

    async def joint_state(self) -> JointState:
        try:
            state = await self.backend.read_joint_state()
        except (BackendError, TimeoutError) as exc:
            raise SafetyRefusal(RefusalCode.NO_STATE, f"cannot read the joint state from the backend: {exc}") from exc
        age = self._clock() - state.stamp
        if not np.isfinite(state.positions).all() or age > MAX_STATE_AGE_S:
            raise SafetyRefusal(RefusalCode.STALE_STATE,
                                f"the joint state is invalid or {age:.3f} s old; refusing to plan or move on it")
        return state

    async def backend_call(self, what: str, awaitable: Awaitable[Any]) -> Any:
        try:
            return await awaitable
        except StoppedBeforeStart as exc:
            raise SafetyRefusal(RefusalCode.STOPPED, f"{what} refused: a stop or e-stop arrived before it started "
                                "(nothing moved)") from exc
        except (BackendError, TimeoutError, NotImplementedError) as exc:
            raise SafetyRefusal(RefusalCode.BACKEND_ERROR, f"the backend could not {what}: {exc}") from exc

    async def robot_state_data(self) -> dict[str, Any]:
        """The state as `RobotState`'s JSON data, not yet validated (see `conversions.robot_state_data`)."""
        state = await self.joint_state()
        try:
            wrench = await self.backend.read_wrench()
        except (BackendError, TimeoutError):
            wrench = None
        gripper = await self.backend.gripper_state() if self.backend.capabilities.gripper else None
        return conversions.robot_state_data(self.robot, state, wrench, gripper)

    async def robot_state(self) -> RobotState:
        return RobotState.model_validate(await self.robot_state_data())

    def safety_envelope(self, registered_tools: list[str]) -> EnvelopeModel:
        return conversions.envelope_model(self.policy, self.robot, registered_tools)

    async def lookup_transform(self, target_frame: str, source_frame: str) -> TransformResult:
        """Two robot-model frames: forward kinematics at the measured joints. Otherwise, on a
        backend with its own frame tree (ROS tf), that tree; else an unknown-frame refusal."""
        frames = set(self.robot.frame_names())
        if not {target_frame, source_frame} <= frames and self.backend.capabilities.transforms:
            found = await self.backend_call("look up the transform",
                                            self.backend.lookup_transform(target_frame, source_frame))
            qx, qy, qz, qw = (float(v) for v in found.rotation_xyzw)
            pose = PoseModel(position=conversions.vector(found.translation), orientation=Quaternion(x=qx, y=qy, z=qz, w=qw))
            return TransformResult(target_frame=target_frame, source_frame=source_frame, pose=pose)
        for name in (target_frame, source_frame):
            if name not in frames:
                shown = ", ".join(sorted(frames)[:40])
                raise SafetyRefusal(RefusalCode.UNKNOWN_FRAME, f"unknown frame {flatten_reason(name, 80)!r}; known "
                                    f"frames: {shown}")
        q = (await self.joint_state()).positions
        relative = self.robot.frame_pose(q, target_frame).as_se3().inverse() * self.robot.frame_pose(q, source_frame).as_se3()
        pose = conversions.pose_model(Pose(relative.translation.copy(), relative.rotation.copy()))
        return TransformResult(target_frame=target_frame, source_frame=source_frame, pose=pose)

    async def list_controllers(self) -> ControllerList:
        allowed = set(self.policy.controllers.allowlist)
        controllers = await self.backend_call("list controllers", self.backend.list_controllers())
        return ControllerList(controllers=[ControllerModel(name=c.name, type=c.type, state=c.state,
                                                           switchable=c.name in allowed) for c in controllers])

    async def graph(self) -> GraphModel:
        graph = await self.backend_call("read the graph", self.backend.graph())
        return GraphModel(**{key: sorted(graph.get(key, [])) for key in ("nodes", "topics", "services", "actions")})

    async def camera(self, camera: str) -> tuple[int, int, float, bytes]:
        """(width, height, stamp, PNG) of an allowlisted camera, downscaled to the policy's width."""
        checks.check_camera(self.policy, camera)
        image = await self.backend_call("take a snapshot", self.backend.camera_snapshot(camera))
        png, width, height = image.png, image.width, image.height
        limit = self.policy.perception.max_image_width
        if width > limit:
            from armwarden.preview.images import downscale_png, pillow_available

            if not pillow_available():
                raise SafetyRefusal(RefusalCode.IMAGE_TOO_WIDE, f"the image is {width} px wide (limit {limit}) and "
                                    "Pillow, which shrinks it, is missing from this environment: reinstall armwarden")
            png, width, height = await anyio.to_thread.run_sync(downscale_png, png, limit)
        return width, height, image.stamp, png
