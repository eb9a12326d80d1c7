"""The ROS 2 backend's graph part: the nodes, topics, services and actions the backend's node sees.

What the `list_ros_graph` tool answers, read from the node's own discovery (no service call), so
it needs only a running node: the names with their types, without the hidden action topics and
services (`/_action/`), which the actions list names once each.
"""

from __future__ import annotations

import rclpy.action.graph

from armwarden.backends.parts import Graph
from armwarden.backends.ros2.bridge import RosBridge


class Ros2Graph(Graph):
    """The graph as `bridge`'s node discovers it."""

    def __init__(self, bridge: RosBridge) -> None:
        self._bridge = bridge

    async def describe(self) -> dict[str, list[str]]:
        node = self._bridge.node

        def typed(pairs: list[tuple[str, list[str]]]) -> list[str]:
            return [f"{name} [{', '.join(types)}]" for name, types in pairs if "/_action/" not in name]

        nodes = [f"{ns.rstrip('/')}/{name}" for name, ns in node.get_node_names_and_namespaces()]
        return {
            "nodes": nodes,
            "topics": typed(node.get_topic_names_and_types()),
            "services": typed(node.get_service_names_and_types()),
            "actions": typed(rclpy.action.graph.get_action_names_and_types(node)),
        }


__all__ = ["Ros2Graph"]
