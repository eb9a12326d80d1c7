"""Each pytest-xdist worker of the ROS run gets a domain of its own (tests_ros/domains.py)."""

from __future__ import annotations

import os

from tests_ros.domains import DOMAINS, TEST_DOMAIN_ENV, worker_domain


def test_workers_of_one_lane_get_distinct_domains():
    assert len({worker_domain(42, f"gw{k}") for k in range(8)}) == 8


def test_a_domain_near_the_top_wraps_into_the_valid_range():
    assert [worker_domain(DOMAINS, f"gw{k}") for k in range(3)] == [DOMAINS, 1, 2]


def test_without_xdist_the_lane_domain_is_kept():
    assert worker_domain(17, None) == 17


def test_this_process_runs_on_the_domain_its_worker_chose(ros_local_domain: int):
    assert os.environ["ROS_DOMAIN_ID"] == os.environ.get(TEST_DOMAIN_ENV, str(ros_local_domain)) == str(ros_local_domain)
    assert os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
