"""The names the MuJoCo cell gives its parts: the model builder creates them, the backend and the
tests look them up by these names (one spelling, so neither side can drift)."""

#: prefix of the envelope capsules' geom names (then the capsule's name)
ENVELOPE_PREFIX = "envelope/"
#: name of the site at the flange carrying the force/torque sensor
FLANGE_SITE = "flange"
FORCE_SENSOR = "flange_force"
TORQUE_SENSOR = "flange_torque"
#: tendon (sum of the two finger openings = gripper width [m]) and its actuator
GRIPPER_TENDON = "gripper_width"
GRIPPER_ACTUATOR = "gripper"
TABLE_GEOM = "table"
FLOOR_GEOM = "floor"
#: geom group of shapes that exist for the envelope only (not rendered by default, no contacts)
HIDDEN_GROUP = 3

__all__ = ["ENVELOPE_PREFIX", "FLANGE_SITE", "FLOOR_GEOM", "FORCE_SENSOR", "GRIPPER_ACTUATOR", "GRIPPER_TENDON",
           "HIDDEN_GROUP", "TABLE_GEOM", "TORQUE_SENSOR"]
