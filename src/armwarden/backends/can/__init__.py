"""Raw CAN actuators (MIT mode, RobStride) driven over python-can, in the agreed backend layout.

The backend: `backend` (`CanBackend`: builds the actuators, the frames out and the fingers, starts
and releases them; `create_backend`), `config` (the `--backend-config` schema), `arm` (`CanArm`:
the servo loop's hooks, execution, stops, damping, faults and the arm state), `command_stream` (the
frames sent each tick: following, holding, damping), `gripper` (the fingers, the cell's gripper
part, and their motion law), `actuators` (what each actuator last reported), `health` (the fault
conditions looked at every tick), `bring_up` (start-up and shut-down frames), `testing` (how the
test harness builds it).
The protocol: `command` (the five-value impedance command both protocols carry), `mit` and
`robstride` / `robstride_frames` / `robstride_device` (pure frame codecs, no I/O), `ranges` and
`mapping` (value ranges and float ↔ uint), `errors`, `bus` (the python-can bus, its reader and
flags). The emulator: `emulator` (the virtual-bus side) and `emulated_actuator` (the motor model).
Importing this package does not import python-can; `bus` and `emulator` do.
"""
