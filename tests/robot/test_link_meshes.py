"""Each link's collision surface as a mesh in the link frame: where Pinocchio places the geometry,
and primitives as closed polytopes enclosing them."""

from __future__ import annotations

from pathlib import Path

import coal  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow
import numpy as np
import pinocchio as pin  # pyright: ignore[reportMissingImports] - cmeel installs it behind a .pth hook pyright cannot follow
import pytest

from armwarden.core.errors import RobotModelError
from armwarden.robot.description_files import load_description
from armwarden.robot.fitting_mesh import LinkMesh, SignedDistance, is_closed, load_mesh, mesh_distances, winding_numbers
from armwarden.robot.link_meshes import link_meshes, shape_mesh
from tests.robot.generated_arm import write_random_arm


def _placed(points: np.ndarray, placement: pin.SE3) -> np.ndarray:
    return points @ placement.rotation.T + placement.translation


def _nearest(points: np.ndarray, cloud: np.ndarray) -> np.ndarray:
    return np.min(np.linalg.norm(points[:, None, :] - cloud[None, :, :], axis=2), axis=1)


def test_each_link_surface_sits_where_pinocchio_places_the_mesh_files(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path, seed=4, n_joints=6, gripper=True)
    description = load_description(arm.urdf)
    model, geometry = description.model, description.collision
    assert geometry is not None
    meshes = link_meshes(description)
    data, geometry_data = model.createData(), pin.GeometryData(geometry)
    pin.framesForwardKinematics(model, data, pin.randomConfiguration(model))
    pin.updateGeometryPlacements(model, data, geometry, geometry_data)
    on_links: dict[str, list[np.ndarray]] = {}
    for index, obj in enumerate(geometry.geometryObjects):
        link = model.frames[obj.parentFrame].name
        path = Path(obj.meshPath)
        from_file = load_mesh(link, path.read_bytes(), "stl", path.name).vertices * obj.meshScale
        expected = _placed(from_file, geometry_data.oMg[index])
        placed = _placed(meshes[link].vertices, data.oMf[obj.parentFrame])
        assert _nearest(expected, placed).max() < 1e-12, link
        on_links.setdefault(link, []).append(expected)
    assert set(meshes) == set(on_links) and len(meshes) == 6 + 1 + 2 + 1  # links, hand, fingers, base
    for link, mesh in meshes.items():  # and nothing else: every surface vertex comes from a file
        placed = _placed(mesh.vertices, data.oMf[model.getFrameId(link, pin.FrameType.BODY)])
        assert _nearest(placed, np.vstack(on_links[link])).max() < 1e-12, link


def test_a_mesh_scale_is_applied(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path, seed=4, n_joints=4)
    plain = link_meshes(load_description(arm.urdf))["link2"]
    text = arm.urdf.read_text(encoding="utf-8").replace('meshes/link2.stl"/>', 'meshes/link2.stl" scale="2 3 0.5"/>')
    arm.urdf.write_text(text, encoding="utf-8")
    scaled = link_meshes(load_description(arm.urdf))["link2"]
    assert np.allclose(np.ptp(scaled.vertices, axis=0), np.ptp(plain.vertices, axis=0) * [2.0, 3.0, 0.5], atol=1e-12)


def test_a_link_without_collision_geometry_has_no_surface(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path, seed=4, n_joints=4)
    assert "tool0" not in link_meshes(load_description(arm.urdf))


def test_a_description_loaded_without_collision_is_refused(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path, seed=4, n_joints=4)
    with pytest.raises(RobotModelError, match="without its collision geometry"):
        link_meshes(load_description(arm.urdf, with_collision=False))


def test_the_same_description_gives_the_same_arrays(tmp_path: Path) -> None:
    arm = write_random_arm(tmp_path, seed=4, n_joints=5, gripper=True)
    first, second = link_meshes(load_description(arm.urdf)), link_meshes(load_description(arm.urdf))
    assert all(np.array_equal(first[k].vertices, second[k].vertices) and np.array_equal(first[k].triangles, second[k].triangles)
               and np.array_equal(first[k].components, second[k].components) for k in first)


def _edges_shared_twice(triangles: np.ndarray) -> bool:
    edges = np.sort(np.vstack([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    return bool(np.all(counts == 2))


@pytest.mark.parametrize(("shape", "half_extent"), [
    (coal.Box(0.1, 0.2, 0.3), (0.05, 0.1, 0.15)),
    (coal.Sphere(0.05), (0.05, 0.05, 0.05)),
    (coal.Capsule(0.04, 0.1), (0.04, 0.04, 0.09)),
    (coal.Ellipsoid(0.02, 0.05, 0.08), (0.02, 0.05, 0.08)),
    (coal.Cylinder(0.03, 0.2), (0.03, 0.03, 0.1)),
], ids=["box", "sphere", "capsule", "ellipsoid", "cylinder"])
def test_a_primitive_becomes_a_closed_mesh_with_the_primitives_bounds(shape: object, half_extent: tuple) -> None:
    mesh = shape_mesh("link", shape, "primitive")
    assert _edges_shared_twice(mesh.triangles)
    upper = mesh.vertices.max(axis=0)
    # enclosing polytopes stand out by at most the sagitta of their facets (24 around, 12 bands: < 4 %)
    assert np.all(upper >= np.asarray(half_extent) - 1e-12) and np.all(upper <= np.asarray(half_extent) * 1.04)
    assert np.allclose(mesh.vertices.min(axis=0), -upper, atol=1e-12)


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


def test_an_mjcf_floor_is_not_a_link_surface(tmp_path: Path) -> None:
    path = tmp_path / "arm.xml"
    path.write_text("<mujoco><worldbody><geom name='floor' type='plane' size='1 1 0.1'/><body name='base'>"
                    "<geom type='box' size='.1 .1 .1'/><body name='l1'><joint name='j1' type='hinge'/>"
                    "<geom type='capsule' size='0.05 0.1'/></body></body></worldbody></mujoco>", encoding="utf-8")
    assert sorted(link_meshes(load_description(path))) == ["base", "l1"]


def _winding_numbers_numpy(points: np.ndarray, vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """The Van Oosterom–Strackee sum in numpy: the oracle of the compiled kernel."""
    rel = vertices[triangles][None, :, :, :] - points[:, None, None, :]  # (N, M, 3, 3)
    a, b, c = rel[:, :, 0], rel[:, :, 1], rel[:, :, 2]
    la, lb, lc = (np.linalg.norm(v, axis=-1) for v in (a, b, c))
    det = np.einsum("nmi,nmi->nm", a, np.cross(b, c))
    den = (la * lb * lc + np.einsum("nmi,nmi->nm", a, b) * lc + np.einsum("nmi,nmi->nm", b, c) * la
           + np.einsum("nmi,nmi->nm", c, a) * lb)
    return np.sum(2.0 * np.arctan2(det, den), axis=1) / (4.0 * np.pi)


def test_the_compiled_winding_numbers_equal_the_numpy_formula_inside_outside_and_near_the_surface() -> None:
    mesh = shape_mesh("link", coal.Capsule(0.04, 0.1), "primitive")
    rng = np.random.default_rng(11)
    points = np.vstack([rng.uniform(-0.1, 0.1, size=(300, 3)),  # inside, outside
                        mesh.vertices[:50] * (1 + rng.uniform(-1e-3, 1e-3, size=(50, 1)))])  # at the surface
    compiled = winding_numbers(points, mesh.vertices, mesh.triangles)
    np.testing.assert_allclose(compiled, _winding_numbers_numpy(points, mesh.vertices, mesh.triangles), atol=1e-12)
    assert np.any(compiled > 0.99) and np.any(np.abs(compiled) < 0.01)  # both sides were asked


def _ring() -> LinkMesh:
    """A thick ring: closed, and not convex (its hole is outside)."""
    import trimesh  # pyright: ignore[reportMissingImports] - the `fit` extra, in dev

    ring = trimesh.creation.annulus(r_min=0.03, r_max=0.06, height=0.05, sections=24)
    return LinkMesh("ring", np.asarray(ring.vertices, dtype=float), np.asarray(ring.faces, dtype=np.int64), "annulus")


def _points_around(mesh: LinkMesh, seed: int) -> np.ndarray:
    """Points all over the mesh's box (inside, outside, in the hole) and just off its surface."""
    rng = np.random.default_rng(seed)
    lo, hi = mesh.vertices.min(axis=0) - 0.01, mesh.vertices.max(axis=0) + 0.01
    near = mesh.vertices[rng.integers(0, len(mesh.vertices), 100)] * (1 + rng.uniform(-2e-3, 2e-3, size=(100, 1)))
    return np.vstack([rng.uniform(lo, hi, size=(400, 3)), near])


def _winding_signed(mesh: LinkMesh, points: np.ndarray) -> np.ndarray:
    inside = winding_numbers(points, mesh.vertices, mesh.triangles) > 0.5
    return np.where(inside, 1.0, -1.0) * mesh_distances(mesh, points)


def test_a_ring_is_closed_and_loses_that_with_a_missing_or_flipped_triangle() -> None:
    ring = _ring()
    flipped = ring.triangles.copy()
    flipped[0] = flipped[0, ::-1]
    assert is_closed(ring.triangles)
    assert not is_closed(ring.triangles[1:])
    assert not is_closed(flipped)


def test_the_signed_distance_on_a_closed_surface_is_the_winding_numbers_with_fewer_sums() -> None:
    ring = _ring()
    points = _points_around(ring, seed=3)
    signed = SignedDistance(ring)
    depth = signed(points)
    np.testing.assert_array_equal(depth, _winding_signed(ring, points))
    assert np.any(depth > 0) and np.any(depth < 0)
    # asked again, points farther from the surface than any node of the 4 mm grid is from them
    # take their nodes' signs, summed the first time: no winding number is summed for them
    far = points[np.abs(depth) > 0.004]
    before = signed.summed
    np.testing.assert_array_equal(signed(far), depth[np.abs(depth) > 0.004])
    assert len(far) > 100 and signed.summed == before


def test_the_signed_distance_on_an_open_surface_sums_every_point() -> None:
    ring = _ring()
    open_ring = LinkMesh("ring", ring.vertices, ring.triangles[1:], "annulus less a triangle")
    points = _points_around(open_ring, seed=4)
    signed = SignedDistance(open_ring)
    np.testing.assert_array_equal(signed(points), _winding_signed(open_ring, points))
    assert signed.summed == len(points)
