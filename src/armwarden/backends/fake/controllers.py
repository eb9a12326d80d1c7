"""The fake backend's simulated ros2_control set-up: its controllers, their switching rules and the
ROS graph it reports, read from the robot profile (`controllers`, `ros`) of a `builtin:<name>`
robot. A user's URDF has no profile: the fake then reports a generic set (one trajectory
controller `arm_controller`, no driver-specific names), never another robot's names.

`FakeControllers` is the set and its switching rules; the cell's parts are `FakeControllerManager`
(listing and switching) and `FakeGraph` (the ROS graph such a cell would show).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

from armwarden.backends.fake.knobs import FakeKnobs
from armwarden.backends.parts import Controllers, Graph
from armwarden.backends.values import ControllerInfo
from armwarden.core.errors import BackendError
from armwarden.robots import ControllerEntry, ControllersProfile, RobotProfile, RosProfile

#: what a robot without a profile reports: one joint trajectory controller, no driver of its own
GENERIC_CONTROLLERS = ControllersProfile(
    trajectory="arm_controller",
    arm_command_types=("joint_trajectory_controller/",),
    loaded=(ControllerEntry(name="arm_controller", type="joint_trajectory_controller/JointTrajectoryController",
                            state="active"),),
)
GENERIC_ROS = RosProfile(trajectory_action="/arm_controller/follow_joint_trajectory")


@dataclass
class FakeControllers:
    """The controllers by name, the one that executes trajectories and the driver's ROS names."""

    controllers: dict[str, ControllerInfo]
    trajectory: str
    arm_command_types: tuple[str, ...]
    ros: RosProfile

    @classmethod
    def for_profile(cls, profile: RobotProfile | None,
                    controllers: Sequence[ControllerInfo | tuple[str, str, str]] | None = None) -> FakeControllers:
        """The profile's set (the generic one without a profile); `controllers` replaces the loaded list."""
        spec = profile.controllers if profile is not None and profile.controllers is not None else GENERIC_CONTROLLERS
        ros = profile.ros if profile is not None and profile.ros is not None else GENERIC_ROS
        loaded = ([ControllerInfo(*c) if isinstance(c, tuple) else c for c in controllers] if controllers
                  else [ControllerInfo(entry.name, entry.type, entry.state) for entry in spec.loaded])
        return cls({c.name: c for c in loaded}, spec.trajectory, spec.arm_command_types, ros)

    def require_trajectory_active(self) -> None:
        """BackendError while the trajectory controller is loaded and inactive."""
        controller = self.controllers.get(self.trajectory)
        if controller is not None and controller.state != "active":
            raise BackendError(f"{self.trajectory} is not active; the arm cannot follow a trajectory")

    def switch(self, activate: tuple[str, ...], deactivate: tuple[str, ...], *, arm_busy: bool) -> None:
        """Switch as ros2_control would, or refuse the whole switch (nothing changes)."""
        unknown = [name for name in (*activate, *deactivate) if name not in self.controllers]
        if unknown:
            raise BackendError(f"unknown controller(s) {unknown}; available: {sorted(self.controllers)}")
        both = sorted(set(activate) & set(deactivate))
        if both:
            raise BackendError(f"controller(s) {both} both activated and deactivated")
        if (activate or deactivate) and arm_busy:
            raise BackendError("cannot switch controllers while a trajectory is executing")
        states = {name: info.state for name, info in self.controllers.items()}
        states.update(dict.fromkeys(deactivate, "inactive"))
        states.update(dict.fromkeys(activate, "active"))
        commanding = [name for name, state in states.items()
                      if state == "active" and self.controllers[name].type.startswith(self.arm_command_types)]
        if len(commanding) > 1:
            raise BackendError(f"controllers {commanding} would both claim the arm's command interfaces")
        self.controllers = {name: ControllerInfo(name, info.type, states[name]) for name, info in self.controllers.items()}

    def graph(self, *, wrench: bool, cameras: Sequence[str]) -> dict[str, list[str]]:
        """The nodes, topics, services and actions a cell with this driver would show."""
        ros = self.ros
        topics = ["/joint_states", "/robot_description", "/tf", "/tf_static"]
        topics += [ros.gripper_joint_states] if ros.gripper_joint_states else []
        topics += [ros.wrench_topic] if wrench and ros.wrench_topic else []
        topics += [f"/cameras/{name}/image_raw" for name in cameras]
        nodes = sorted(["/armwarden_fake", "/controller_manager", "/robot_state_publisher", *ros.nodes])
        return {
            "nodes": nodes + [f"/{name}" for name in self.controllers],
            "topics": sorted(topics),
            "services": sorted(["/controller_manager/list_controllers", "/controller_manager/switch_controller",
                                *ros.services]),
            "actions": sorted([ros.trajectory_action, *ros.actions]),
        }


class FakeControllerManager(Controllers):
    """The controllers part of the fake cell; a switch counts as an actuation before its checks."""

    def __init__(self, controllers: FakeControllers, arm_busy: Callable[[], bool], knobs: FakeKnobs) -> None:
        self._controllers = controllers
        self._arm_busy = arm_busy  # a trajectory is executing
        self._knobs = knobs

    async def list(self) -> list[ControllerInfo]:
        return list(self._controllers.controllers.values())

    async def switch(self, activate: tuple[str, ...], deactivate: tuple[str, ...]) -> None:
        self._knobs.count_actuation()
        self._controllers.switch(activate, deactivate, arm_busy=self._arm_busy())


class FakeGraph(Graph):
    """The graph part of the fake cell: the nodes, topics, services and actions of its driver,
    with the wrench topic and camera topics only for the parts the cell has."""

    def __init__(self, controllers: FakeControllers, *, wrench: bool, cameras: tuple[str, ...]) -> None:
        self._controllers, self._wrench, self._cameras = controllers, wrench, cameras

    async def describe(self) -> dict[str, list[str]]:
        return self._controllers.graph(wrench=self._wrench, cameras=self._cameras)


__all__ = ["GENERIC_CONTROLLERS", "GENERIC_ROS", "FakeControllerManager", "FakeControllers", "FakeGraph"]
