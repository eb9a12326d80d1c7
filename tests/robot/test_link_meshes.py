"""Each link's collision surface as a mesh in the link frame: where Pinocchio places the geometry,
and primitives as closed polytopes enclosing them."""

from __future__ import annotations

from pathlib import Path

import coal  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow
import numpy as np
import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow
import pytest

from armwarden.robot.description_files import load_description
from armwarden.robot.fitting_mesh import winding_numbers
from armwarden.robot.link_meshes import link_meshes, shape_mesh
from tests.robot.generated_arm import write_random_arm


def test_each_link_surface_sits_where_pinocchio_places_the_geometry(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path, seed=4, n_joints=6, gripper=True)
    description = load_description(arm.urdf)
    model, geometry = description.model, description.collision
    assert geometry is not None
    meshes = link_meshes(description)
    data, geometry_data = model.createData(), pin.GeometryData(geometry)
    q = pin.randomConfiguration(model)
    pin.framesForwardKinematics(model, data, q)
    pin.updateGeometryPlacements(model, data, geometry, geometry_data)
    for index, obj in enumerate(geometry.geometryObjects):
        link = model.frames[obj.parentFrame].name
        shape = shape_mesh(link, obj.geometry, "")
        expected = shape.vertices @ geometry_data.oMg[index].rotation.T + geometry_data.oMg[index].translation
        placed = meshes[link].vertices @ data.oMf[obj.parentFrame].rotation.T + data.oMf[obj.parentFrame].translation
        distances = np.min(np.linalg.norm(expected[:, None, :] - placed[None, :, :], axis=2), axis=1)
        assert distances.max() < 1e-12, link


@pytest.mark.parametrize(("shape", "surface"), [
    (coal.Sphere(0.05), lambda u: 0.05 * u),
    (coal.Capsule(0.04, 0.1), lambda u: 0.04 * u + np.where(u[:, 2:3] > 0, [0.0, 0.0, 0.05], [0.0, 0.0, -0.05])),
    (coal.Ellipsoid(0.02, 0.05, 0.08), lambda u: u * [0.02, 0.05, 0.08]),
    (coal.Cylinder(0.03, 0.2), lambda u: np.column_stack([0.03 * u[:, :2] / np.linalg.norm(u[:, :2], axis=1, keepdims=True),
                                                          0.1 * u[:, 2]])),
], ids=["sphere", "capsule", "ellipsoid", "cylinder"])
def test_a_round_primitive_becomes_a_polytope_that_encloses_it(shape: object, surface) -> None:
    units = np.random.default_rng(5).normal(size=(4000, 3))
    units /= np.linalg.norm(units, axis=1, keepdims=True)
    mesh = shape_mesh("link", shape, "primitive")
    inside = winding_numbers(surface(units), mesh.vertices, mesh.triangles)
    assert np.all(inside > 0.5)  # every point of the true surface is inside (the polytope is closed and outward)
