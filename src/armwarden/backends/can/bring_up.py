"""The CAN backend's start-up and shut-down frames: the steps before the servo loop holds the arm.

Start-up: ping every actuator (RobStride type 0; MIT: the exit-motor-mode frame, which every MIT
actuator answers and which leaves it disabled), read positions (RobStride: a stop frame, answered
with feedback), write and read back the actuator-side CAN timeout (RobStride 0x7028; MIT mode has
no frame for it: the firmware's own setting applies), refuse a RobStride actuator whose run_mode
(0x7005) is not 0 (operation/MIT mode; naming the joint), write and read back each RobStride
actuator's configured torque limit (0x700B limit_torque; MIT: the firmware's). A missing reply
refuses to open (`BackendError` naming the joints and ids; the daemon exits 2). The backend
enables the actuators only at the very end (`enable_frame`), when the servo loop is about to hold
them; closing disables them (`disable_frame`).

Each frame goes out through the backend's `send` (which makes its actuator owe a reply); each
step waits for every actuator's answer through its `await_all`.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable, Iterable, Sequence
from typing import TYPE_CHECKING

import numpy as np

from armwarden.backends.can import mit
from armwarden.backends.can import robstride as rs
from armwarden.backends.can import robstride_frames as rs_frames
from armwarden.backends.can.actuators import Actuator, OutFrame
from armwarden.backends.can.bus import FrameKind
from armwarden.backends.can.command import MotorCommand
from armwarden.backends.can.config import Config, SimulatedLoad
from armwarden.backends.can.emulated_actuator import ActuatorSpec
from armwarden.backends.can.emulated_arm import ArmDynamics
from armwarden.backends.can.emulator import ActuatorEmulator, ArmSetup
from armwarden.backends.can.ranges import Protocol
from armwarden.core.errors import BackendError

if TYPE_CHECKING:
    from armwarden.robot.model import RobotModel

#: send frames in order, each actuator then owing a reply
Send = Callable[[list[OutFrame], FrameKind], None]
#: wait until every actuator is `ready`, else `BackendError` naming those that are not and `what`
AwaitAll = Callable[[Callable[[Actuator], bool], str], Awaitable[None]]


def rs_frame(a: Actuator, frame: rs.Frame) -> OutFrame:
    return OutFrame(a, frame.arbitration_id, frame.data, True)


def mit_frame(a: Actuator, data: bytes) -> OutFrame:
    return OutFrame(a, a.joint.can_id, data, False)


def command_frame(a: Actuator, command: MotorCommand) -> OutFrame:
    """`command` for `a` as a frame; `BackendError` (nothing sent) if the model cannot carry it."""
    try:
        if a.joint.protocol is Protocol.ROBSTRIDE:
            return rs_frame(a, rs_frames.control_frame(a.joint.can_id, command, a.ranges))
        return mit_frame(a, mit.pack_command(command, a.ranges))
    except ValueError as exc:  # a value the model cannot carry: never sent
        raise BackendError(f"can backend: {a.label}: command refused: {exc}") from exc


def enable_frame(a: Actuator, host_id: int) -> OutFrame:
    if a.joint.protocol is Protocol.ROBSTRIDE:
        return rs_frame(a, rs_frames.enable_frame(a.joint.can_id, host_id))
    return mit_frame(a, mit.Special.ENTER_MOTOR_MODE.value)


def disable_frame(a: Actuator, host_id: int) -> OutFrame:
    """Zero torque (RobStride: a stop frame; MIT: exit motor mode)."""
    if a.joint.protocol is Protocol.ROBSTRIDE:
        return rs_frame(a, rs_frames.stop_frame(a.joint.can_id, host_id))
    return mit_frame(a, mit.Special.EXIT_MOTOR_MODE.value)


async def configure_actuators(everyone: Sequence[Actuator], config: Config, send: Send, await_all: AwaitAll) -> None:
    """Steps 1-3 of the start-up (see the module docstring): nothing is enabled yet."""
    host = config.host_id
    robstride = [a for a in everyone if a.joint.protocol is Protocol.ROBSTRIDE]
    # 1. ping (harmless: MIT exit-mode leaves the actuator disabled and answers with its state)
    for a in everyone:
        if a.joint.protocol is Protocol.ROBSTRIDE:
            send([rs_frame(a, rs_frames.get_id_frame(a.joint.can_id, host))], FrameKind.QUERY)
        else:
            send([mit_frame(a, mit.Special.EXIT_MOTOR_MODE.value)], FrameKind.QUERY)
    await await_all(lambda a: a.pinged, "did not answer the ping")
    # 2. positions: a RobStride stop frame (disabled already) is answered with feedback
    for a in robstride:
        send([rs_frame(a, rs_frames.stop_frame(a.joint.can_id, host))], FrameKind.MODE)
    await await_all(lambda a: a.raw_position is not None, "reported no position")
    # 3. actuator-side CAN timeout (RobStride 0x7028), written and read back
    ticks = rs.can_timeout_ticks(config.can_timeout_s)
    for a in robstride:
        send([rs_frame(a, rs_frames.write_parameter_frame(a.joint.can_id, host, rs.CAN_TIMEOUT, ticks))], FrameKind.PARAMETER)
        send([rs_frame(a, rs_frames.read_parameter_frame(a.joint.can_id, host, rs.CAN_TIMEOUT))], FrameKind.PARAMETER)
    await await_all(lambda a: a.joint.protocol is Protocol.MIT or a.parameters.get(rs.CAN_TIMEOUT.index) == ticks,
                    f"did not confirm canTimeout = {ticks} ticks ({config.can_timeout_s} s)")
    # 3b. RobStride: operation (MIT-style) control mode, or nothing is enabled; the torque limit
    # written (0x700B limit_torque) and read back
    for a in robstride:
        send([rs_frame(a, rs_frames.read_parameter_frame(a.joint.can_id, host, rs.RUN_MODE))], FrameKind.PARAMETER)
    await await_all(lambda a: a.joint.protocol is Protocol.MIT or rs.RUN_MODE.index in a.parameters,
                    "did not report run_mode (0x7005)")
    wrong = [f"{a.label} is in run_mode {_run_mode_name(a.parameters[rs.RUN_MODE.index])}"
             for a in robstride if a.parameters[rs.RUN_MODE.index] != rs.RunMode.OPERATION]
    if wrong:
        raise BackendError(f"can backend: refusing to enable: {'; '.join(wrong)} (must be 0, operation/MIT mode)")
    for a in robstride:
        send([rs_frame(a, rs_frames.write_parameter_frame(a.joint.can_id, host, rs.LIMIT_TORQUE, a.joint.torque_limit_nm))],
             FrameKind.PARAMETER)
        send([rs_frame(a, rs_frames.read_parameter_frame(a.joint.can_id, host, rs.LIMIT_TORQUE))], FrameKind.PARAMETER)
    await await_all(lambda a: a.joint.protocol is Protocol.MIT or _confirms(
        a.parameters.get(rs.LIMIT_TORQUE.index), a.joint.torque_limit_nm), "did not confirm its limit_torque (0x700B)")


def build_emulator(config: Config, arm: Sequence[Actuator], home: Iterable[float],
                   robot: RobotModel | None = None) -> ActuatorEmulator:
    """The emulated actuators `config.simulate` asks for: the arm at `home` [rad], the gripper open;
    under `dynamics: robot_model` the arm's actuators move `robot`'s body together (simulated time
    runs at `speedup`, as the backend's trajectories and its `Cell.time_scale` do)."""
    simulate = config.simulate
    assert simulate is not None
    specs = []
    for a, q in zip(arm, np.asarray(tuple(home), dtype=float), strict=True):
        load = simulate.loads.get(a.joint.name)
        extra = {} if load is None else load.model_dump(exclude={"coulomb_friction_nm"})
        specs.append(ActuatorSpec(
            can_id=a.joint.can_id, model=a.joint.model,
            initial_position_rad=a.joint.direction * float(q) + a.joint.homing_offset_rad,
            # MIT firmware's watchdog is configured outside this protocol; the emulator gets it here
            can_timeout_s=config.can_timeout_s if a.joint.protocol is Protocol.MIT else 0.0,
            **extra,
        ))
    g = config.gripper
    if g is not None:
        load = simulate.loads.get(g.name)
        specs.append(ActuatorSpec(
            can_id=g.can_id, model=g.model, initial_position_rad=g.direction * g.open_position_rad + g.homing_offset_rad,
            can_timeout_s=config.can_timeout_s if g.protocol is Protocol.MIT else 0.0,
            **({} if load is None else load.model_dump(exclude={"coulomb_friction_nm"})),
        ))
    setup = None
    if simulate.dynamics == "robot_model":
        if robot is None:
            raise ValueError("simulate.dynamics robot_model needs the robot model")
        loads = [simulate.loads.get(a.joint.name) or SimulatedLoad() for a in arm]
        setup = ArmSetup(
            model=robot.model, can_ids=tuple(a.joint.can_id for a in arm),
            direction=tuple(float(a.joint.direction) for a in arm),
            offset=tuple(a.joint.homing_offset_rad for a in arm),
            dynamics=ArmDynamics(
                armature_kgm2=tuple(load.inertia_kgm2 for load in loads),
                viscous_nms=tuple(load.damping_nms_per_rad for load in loads),
                coulomb_nm=tuple(load.coulomb_friction_nm for load in loads),
                torque_noise_nm=simulate.torque_noise_nm, mass_error=simulate.mass_error,
                payload_kg=simulate.payload_kg, payload_com_m=simulate.payload_com_m, payload_frame=robot.tcp_frame,
                seed=simulate.seed, brakes=simulate.brakes),
            time_scale=simulate.speedup)
    return ActuatorEmulator(config.bus.channel, specs, interface=config.bus.interface, rate_hz=simulate.rate_hz,
                            host_id=config.host_id, mit_reply_id=config.mit_reply_id, arm=setup)


def _run_mode_name(value: float) -> str:
    try:
        return f"{int(value)} ({rs.RunMode(int(value)).name})"
    except ValueError:
        return f"{value:g} (undefined)"


def _confirms(read_back: float | None, written: float) -> bool:
    """A float32 parameter read back as written (to float32 precision)."""
    return read_back is not None and abs(read_back - written) <= 1e-5 * max(1.0, abs(written))


__all__ = ["AwaitAll", "Send", "build_emulator", "command_frame", "configure_actuators", "disable_frame",
           "enable_frame", "mit_frame", "rs_frame"]
