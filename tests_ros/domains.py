"""A pytest plugin for the ROS run of scripts/test.sh: one ROS domain per pytest-xdist worker.

Every test there starts rclpy endpoints (a cell, a backend, a client) that find each other by
discovery. Two workers on one domain would see each other's `/joint_states` and action servers,
and a test would read another test's arm. So each worker takes the lane's `ROS_DOMAIN_ID` plus its
worker number (wrapped into 1..100), with discovery on this host only, in `os.environ` before any
rclpy context exists: its children inherit it, and `tests_ros/conftest.py`'s session fixture uses
it (`TEST_DOMAIN_ENV`). Load it with ``-p tests_ros.domains``.
"""

from __future__ import annotations

import os
import random

import pytest

#: the domain this worker chose, for `tests_ros/conftest.py`
TEST_DOMAIN_ENV = "ARMWARDEN_TEST_ROS_DOMAIN"
#: domains 1..DOMAINS (0 is everyone's default; above 101 the DDS ports run out on Linux)
DOMAINS = 100


def worker_domain(lane_domain: int, worker: str | None) -> int:
    """`lane_domain` moved by the xdist worker's number ("gw3" → +3), wrapped into 1..DOMAINS."""
    offset = int(worker[2:]) if worker and worker.startswith("gw") and worker[2:].isdigit() else 0
    return 1 + (lane_domain - 1 + offset) % DOMAINS


def pytest_configure(config: pytest.Config) -> None:
    lane = os.environ.get("ROS_DOMAIN_ID", "")
    lane_domain = int(lane) if lane.isdigit() and 1 <= int(lane) <= DOMAINS else random.randint(1, DOMAINS)
    domain = worker_domain(lane_domain, os.environ.get("PYTEST_XDIST_WORKER"))
    os.environ[TEST_DOMAIN_ENV] = str(domain)
    os.environ["ROS_DOMAIN_ID"] = str(domain)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.pop("ROS_STATIC_PEERS", None)
    os.environ.pop("ROS_LOCALHOST_ONLY", None)
