"""The ROS 2 backend's rclpy-free parts on plain message stand-ins: the joint-state and wrench
caches (name matching, stamps that go backwards or freeze, ages), the transform buffer (chains,
stale and disconnected frames) and image conversion (encodings, row padding, malformed data)."""

from __future__ import annotations

import io
from types import SimpleNamespace as Msg

import numpy as np
import pytest
from PIL import Image

from armwarden.backends.ros2.images import png_from_compressed, png_from_image
from armwarden.backends.ros2.state import JointStateCache, WrenchCache
from armwarden.backends.ros2.tf import TransformBuffer
from armwarden.core.errors import BackendError


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def stamp(seconds: float) -> Msg:
    return Msg(sec=int(seconds), nanosec=round((seconds - int(seconds)) * 1e9))


def joint_msg(t: float, names: list[str], positions: list[float], velocities: list[float] | None = None) -> Msg:
    return Msg(header=Msg(stamp=stamp(t)), name=names, position=positions,
               velocity=velocities if velocities is not None else [0.0] * len(names))


# ---------------------------------------------------------------------------- joint states
def test_joint_states_are_matched_by_name_into_policy_order() -> None:
    cache = JointStateCache("/joint_states", ("a", "b"), ("ros_a", "ros_b"), 0.5, Clock())
    cache.accept(joint_msg(1.0, ["ros_b", "other", "ros_a"], [2.0, 9.0, 1.0]))
    state = cache.fresh()
    assert state.names == ("a", "b") and state.positions.tolist() == [1.0, 2.0]


def test_a_message_lacking_a_joint_is_not_a_sample() -> None:
    cache = JointStateCache("/joint_states", ("a", "b"), ("a", "b"), 0.5, Clock())
    cache.accept(joint_msg(1.0, ["a"], [1.0]))
    with pytest.raises(BackendError, match=r"no joint state received on /joint_states yet; 1 message.*lacked b"):
        cache.fresh()


def test_old_joint_states_are_refused_naming_their_age() -> None:
    clock = Clock()
    cache = JointStateCache("/joint_states", ("a",), ("a",), 0.5, clock)
    cache.accept(joint_msg(1.0, ["a"], [0.0]))
    clock.now += 0.83
    with pytest.raises(BackendError, match=r"joint states on /joint_states are 0\.83 s old \(limit 0\.5 s\)"):
        cache.fresh()


def test_a_header_stamp_that_goes_backwards_is_dropped_and_the_state_ages() -> None:
    clock = Clock()
    cache = JointStateCache("/joint_states", ("a",), ("a",), 0.5, clock)
    cache.accept(joint_msg(2.0, ["a"], [0.0]))
    clock.now += 0.6
    cache.accept(joint_msg(1.0, ["a"], [0.5]))
    assert cache.latest().positions.tolist() == [0.0]
    with pytest.raises(BackendError, match="went backwards"):
        cache.fresh()


def test_without_published_velocities_they_are_differenced() -> None:
    clock = Clock()
    cache = JointStateCache("/joint_states", ("a",), ("a",), 0.5, clock)
    cache.accept(joint_msg(1.0, ["a"], [0.0], velocities=[]))
    clock.now += 0.1
    cache.accept(joint_msg(1.1, ["a"], [0.02], velocities=[]))
    assert cache.fresh().velocities.tolist() == pytest.approx([0.2])


def test_non_finite_positions_are_not_a_sample() -> None:
    cache = JointStateCache("/joint_states", ("a",), ("a",), 0.5, Clock())
    cache.accept(joint_msg(1.0, ["a"], [float("nan")]))
    assert cache.latest() is None


# ---------------------------------------------------------------------------- wrench
def wrench_msg(t: float, fz: float = 0.0, frame: str = "base") -> Msg:
    vector = Msg(x=0.0, y=0.0, z=fz)
    return Msg(header=Msg(stamp=stamp(t), frame_id=frame), wrench=Msg(force=vector, torque=Msg(x=0.0, y=0.0, z=0.0)))


def test_a_frozen_wrench_stamp_ages_from_the_last_new_stamp() -> None:
    clock = Clock()
    cache = WrenchCache("/wrench", 0.1, None, clock)
    cache.accept(wrench_msg(1.0, 3.0))
    first = cache.fresh().stamp
    clock.now += 0.2
    cache.accept(wrench_msg(1.0, 5.0))  # same header stamp: not new
    with pytest.raises(BackendError, match=r"0\.20 s old \(limit 0\.1 s\) \(its header stamp stopped advancing\)"):
        cache.fresh()
    assert first == 100.0


def test_a_wrench_in_another_frame_is_not_taken() -> None:
    cache = WrenchCache("/wrench", 0.1, "base", Clock())
    cache.accept(wrench_msg(1.0, frame="tool"))
    with pytest.raises(BackendError, match="no wrench received on /wrench yet"):
        cache.fresh()


# ---------------------------------------------------------------------------- transforms
def tf_msg(parent: str, child: str, xyz: tuple[float, float, float], xyzw: tuple[float, float, float, float]) -> Msg:
    transform = Msg(translation=Msg(x=xyz[0], y=xyz[1], z=xyz[2]),
                    rotation=Msg(x=xyzw[0], y=xyzw[1], z=xyzw[2], w=xyzw[3]))
    return Msg(transforms=[Msg(header=Msg(frame_id=parent), child_frame_id=child, transform=transform)])


QUARTER_TURN_Z = (0.0, 0.0, np.sin(np.pi / 4), np.cos(np.pi / 4))


def test_a_chain_of_transforms_is_composed_both_ways() -> None:
    buffer = TransformBuffer(1.0, Clock())
    buffer.accept(tf_msg("world", "a", (1.0, 0.0, 0.0), QUARTER_TURN_Z), static=True)
    buffer.accept(tf_msg("a", "b", (1.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)), static=True)
    b_in_world = buffer.lookup("world", "b")
    np.testing.assert_allclose(b_in_world.translation, [1.0, 1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(np.abs(b_in_world.rotation_xyzw), np.abs(QUARTER_TURN_Z), atol=1e-12)
    world_in_b = buffer.lookup("b", "world")
    np.testing.assert_allclose(world_in_b.translation, [-1.0, 1.0, 0.0], atol=1e-12)


def test_a_stale_dynamic_transform_is_refused_but_a_static_one_never_ages() -> None:
    clock = Clock()
    buffer = TransformBuffer(1.0, clock)
    buffer.accept(tf_msg("world", "camera", (0.0, 0.0, 1.0), (0.0, 0.0, 0.0, 1.0)), static=True)
    buffer.accept(tf_msg("world", "tool", (0.0, 0.0, 1.0), (0.0, 0.0, 0.0, 1.0)), static=False)
    clock.now += 2.0
    assert buffer.lookup("world", "camera").translation.tolist() == [0.0, 0.0, 1.0]
    with pytest.raises(BackendError, match=r"the transform world -> tool is 2\.00 s old"):
        buffer.lookup("world", "tool")


def test_frames_in_separate_trees_are_refused() -> None:
    buffer = TransformBuffer(1.0, Clock())
    buffer.accept(tf_msg("world", "a", (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)), static=True)
    buffer.accept(tf_msg("map", "b", (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)), static=True)
    with pytest.raises(BackendError, match="are not connected"):
        buffer.lookup("a", "b")


# ---------------------------------------------------------------------------- images
def decoded(png: bytes) -> np.ndarray:
    with Image.open(io.BytesIO(png)) as image:
        return np.asarray(image)


def image_msg(pixels: np.ndarray, encoding: str, pad: int = 0) -> Msg:
    height, width = pixels.shape[:2]
    rows = pixels.reshape(height, -1)
    padded = np.concatenate([rows, np.zeros((height, pad), dtype=np.uint8)], axis=1)
    return Msg(encoding=encoding, width=width, height=height, step=padded.shape[1], data=padded.tobytes())


RGB = np.arange(4 * 5 * 3, dtype=np.uint8).reshape(4, 5, 3)


@pytest.mark.parametrize("encoding", ["rgb8", "bgr8"])
def test_colour_images_become_rgb_pngs_even_with_padded_rows(encoding: str) -> None:
    source = RGB if encoding == "rgb8" else RGB[:, :, ::-1]
    width, height, png = png_from_image(image_msg(np.ascontiguousarray(source), encoding, pad=3))
    assert (width, height) == (5, 4)
    assert np.array_equal(decoded(png), RGB)


def test_mono_and_rgba_images_keep_their_channels() -> None:
    grey = RGB[:, :, 0].copy()
    assert np.array_equal(decoded(png_from_image(image_msg(grey, "mono8"))[2]), grey)
    bgra = np.concatenate([RGB[:, :, ::-1], np.full((4, 5, 1), 7, dtype=np.uint8)], axis=2)
    rgba = decoded(png_from_image(image_msg(np.ascontiguousarray(bgra), "bgra8"))[2])
    assert np.array_equal(rgba[:, :, :3], RGB) and np.all(rgba[:, :, 3] == 7)


def test_an_unsupported_encoding_or_short_data_is_refused() -> None:
    with pytest.raises(BackendError, match="image encoding '16UC1' is not supported"):
        png_from_image(image_msg(RGB, "16UC1"))
    short = image_msg(RGB, "rgb8")
    short.data = short.data[:-1]
    with pytest.raises(BackendError, match="image data does not fit 5x4 rgb8"):
        png_from_image(short)


def test_a_compressed_png_passes_through_and_a_jpeg_is_converted() -> None:
    png = png_from_image(image_msg(RGB, "rgb8"))[2]
    assert png_from_compressed(Msg(format="png", data=png)) == (5, 4, png)
    jpeg = io.BytesIO()
    Image.fromarray(RGB).save(jpeg, format="JPEG")
    width, height, converted = png_from_compressed(Msg(format="jpeg", data=jpeg.getvalue()))
    assert (width, height) == (5, 4) and decoded(converted).shape == (4, 5, 3)
    with pytest.raises(BackendError, match="neither PNG nor JPEG"):
        png_from_compressed(Msg(format="tiff", data=b"II*\x00"))
