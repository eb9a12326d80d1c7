"""The MCP faces of the tools, one module per tool group (see `face.py` for what a face is)."""

from __future__ import annotations

from collections.abc import Callable

from armwarden.server.faces.control import control_faces
from armwarden.server.faces.face import Face, FaceContext, Faces
from armwarden.server.faces.gripper import gripper_faces
from armwarden.server.faces.introspect import introspect_faces
from armwarden.server.faces.motion import motion_faces
from armwarden.server.faces.perception import perception_faces
from armwarden.server.faces.safety import safety_faces
from armwarden.tools import ToolGroup

#: each group's faces, built from one policy and Guard
GROUP_FACES: dict[ToolGroup, Callable[[FaceContext], Faces]] = {
    "introspect": introspect_faces,
    "perception": perception_faces,
    "motion": motion_faces,
    "gripper": gripper_faces,
    "control": control_faces,
    "safety": safety_faces,
}

__all__ = ["GROUP_FACES", "Face", "FaceContext", "Faces"]
