"""Offscreen rendering of the MuJoCo cell's cameras (EGL on headless CPU-only machines)."""

from __future__ import annotations

import numpy as np
import pytest

import armwarden.backends.mujoco  # noqa: F401 - chooses the offscreen GL platform before mujoco loads

mujoco = pytest.importorskip("mujoco")

from armwarden.backends.mujoco.model import build_model  # noqa: E402 - after the importorskip
from armwarden.backends.mujoco.scene import scene_for_policy  # noqa: E402
from armwarden.policy import load_policy  # noqa: E402
from armwarden.policy.loading import bundled_policy  # noqa: E402
from armwarden.robot import build_robot  # noqa: E402
from armwarden.robot.model import resolve_description  # noqa: E402

HEIGHT, WIDTH = 240, 320


@pytest.fixture(scope="module")
def policy():
    return load_policy(bundled_policy("fr3"))


@pytest.fixture(scope="module")
def cell(policy):
    return build_model(resolve_description(policy.robot.description), build_robot(policy), scene_for_policy(policy))


@pytest.fixture(scope="module")
def renderer(cell):
    renderer = mujoco.Renderer(cell.model, HEIGHT, WIDTH)
    yield renderer
    renderer.close()


def render(cell, renderer, q: np.ndarray, camera: str) -> np.ndarray:
    data = mujoco.MjData(cell.model)
    cell.set_arm_positions(data, q)
    mujoco.mj_forward(cell.model, data)
    renderer.update_scene(data, camera=camera)
    return renderer.render().astype(float)


@pytest.mark.parametrize("camera", ["scene", "wrist"])
def test_a_camera_renders_a_picture_that_is_not_blank(cell, renderer, policy, camera):
    image = render(cell, renderer, np.array(policy.robot.home_joint_positions), camera)
    assert image.shape == (HEIGHT, WIDTH, 3)
    assert image.std() > 10.0  # grey levels vary: a scene, not a cleared buffer


def test_the_scene_camera_sees_the_arm_move(cell, renderer, policy):
    home = np.array(policy.robot.home_joint_positions)
    turned = home.copy()
    turned[0] += 1.0  # swing the arm about the base by 1 rad
    before = render(cell, renderer, home, "scene")
    after = render(cell, renderer, turned, "scene")
    changed = np.abs(after - before).max(axis=2) > 30.0
    assert changed.mean() > 0.01  # over 1 % of the pixels changed clearly
