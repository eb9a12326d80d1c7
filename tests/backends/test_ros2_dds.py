"""Which DDS domain and discovery range the ros2 backend (and the fake cell) use when the
environment says nothing, or something: the same defaults on both sides (domain 0, LOCALHOST),
named in every message about a stream that never came. No rclpy needed."""

from __future__ import annotations

import pytest

from armwarden.backends.ros2.dds import dds_settings
from armwarden.backends.ros2.state import JointStateCache, WrenchCache
from armwarden.core.errors import BackendError


def test_an_empty_environment_means_domain_0_on_localhost() -> None:
    settings = dds_settings(None, {})

    assert (settings.domain_id, settings.discovery_range) == (0, "LOCALHOST")
    assert settings.describe() == ("ROS_DOMAIN_ID=0 (unset: the default), "
                                   "ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST (unset: the default)")


def test_the_environment_is_honoured() -> None:
    settings = dds_settings(None, {"ROS_DOMAIN_ID": "42", "ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET"})

    assert settings.describe() == "ROS_DOMAIN_ID=42, ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET"


def test_the_backend_configs_domain_id_wins_over_the_environment() -> None:
    settings = dds_settings(7, {"ROS_DOMAIN_ID": "42"})

    assert settings.domain_id == 7 and "domain_id in the backend config" in settings.describe()


@pytest.mark.parametrize("environ", [{"ROS_DOMAIN_ID": "x"}, {"ROS_DOMAIN_ID": "300"},
                                     {"ROS_AUTOMATIC_DISCOVERY_RANGE": "LAN"}])
def test_a_malformed_value_is_refused(environ: dict[str, str]) -> None:
    with pytest.raises(BackendError, match="ROS_"):
        dds_settings(None, environ)


def test_the_default_range_is_put_into_the_environment_rcl_reads() -> None:
    unset: dict[str, str] = {}
    dds_settings(None, unset).apply(unset)
    chosen = {"ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET"}
    dds_settings(None, chosen).apply(chosen)

    assert unset == {"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    assert chosen == {"ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET"}


def test_no_joint_state_yet_names_the_domain_and_range_and_how_to_agree() -> None:
    settings = dds_settings(None, {"ROS_DOMAIN_ID": "42"})
    cache = JointStateCache("/joint_states", ("a",), ("a",), 0.5, network=settings)

    with pytest.raises(BackendError) as raised:
        cache.fresh()

    message = str(raised.value)
    assert "no joint state received on /joint_states yet" in message
    assert "ROS_DOMAIN_ID=42" in message and "ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST" in message
    assert "same ROS_DOMAIN_ID" in message


def test_no_wrench_yet_names_the_domain_and_range() -> None:
    cache = WrenchCache("/wrench", 0.1, None, network=dds_settings(None, {}))

    with pytest.raises(BackendError, match=r"ROS_DOMAIN_ID=0 .*ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST"):
        cache.fresh()
