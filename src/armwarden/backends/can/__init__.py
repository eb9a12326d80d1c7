"""Raw CAN actuators: protocol codecs (MIT mode, RobStride), a python-can bus layer and an emulator.

One module per job: `ranges` (per-model value ranges), `mapping` (float <-> uint), `mit` and
`robstride` (pure frame codecs, no I/O), `bus` (python-can bus, reader, health), `emulator`
(simulated actuators on the virtual bus). Importing this package does not import python-can;
`bus` and `emulator` do.
"""
