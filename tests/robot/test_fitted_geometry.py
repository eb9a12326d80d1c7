"""Capsules fitted to collision meshes (armwarden.robot.fitting) and the bundled FR3 data file.

The fitter is exercised on meshes built here (a box, an L, two separate boxes): containment of the
whole surface and the inside with the margin, a tighter fit with several capsules where one is fat,
same input same bytes. The bundled file is checked against Franka's collision-mesh vertices, per link, when the
vertex cloud is present (tests/robot/data/README.md says why it is not committed and how to make it).
"""

from __future__ import annotations

import hashlib
import math
import os
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from armwarden.robot.fitted_file import FittingError, load_fitted, render_fitted
from armwarden.robot.fitting import FitOptions, fit_link, rotate_fit
from armwarden.robot.fitting_mesh import (
    LinkMesh,
    box_mesh,
    capsule_surface_points,
    load_mesh,
    merge_meshes,
    point_segment_distances,
    subdivide,
    winding_numbers,
)
from armwarden.robot.model import resolve_description
from tests.helpers import SRC

URDF_PATH = resolve_description("builtin:fr3")
FITTED_PATH = URDF_PATH.parent / "fitted.yaml"
DATA = Path(__file__).resolve().parent / "data"
CLOUD_PATH = Path(os.environ.get("ARMWARDEN_FR3_VERTICES", DATA / "fr3_collision_vertices.npz"))
FAST = FitOptions(max_bodies=2, simplex_evaluations=300, lloyd_iterations=6, surface_spacing_m=0.004)


def inside_depth(points: np.ndarray, bodies) -> np.ndarray:
    """How deep each point lies inside the union of capsules (negative: outside)."""
    p0 = np.array([b.p0_m for b in bodies])
    p1 = np.array([b.p1_m for b in bodies])
    radii = np.array([b.radius_m for b in bodies])
    return np.max(radii[None, :] - point_segment_distances(points, p0, p1), axis=1)


def surface_samples(mesh: LinkMesh, spacing: float) -> np.ndarray:
    """Points covering every triangle of `mesh` (its pieces' corners and centroids)."""
    points, pieces = subdivide(mesh.vertices, mesh.triangles, spacing)
    return np.vstack([points, points[pieces].mean(axis=1)])


def l_shape() -> LinkMesh:
    """One closed surface: an L (a 0.24 m foot, a 0.30 m upright, 0.06 m thick) extruded 0.06 m."""
    outline = np.array([(0.0, 0.0), (0.24, 0.0), (0.24, 0.06), (0.06, 0.06), (0.06, 0.30), (0.0, 0.30)])  # counter-clockwise
    n = len(outline)
    vertices = np.vstack([np.c_[outline, np.zeros(n)], np.c_[outline, np.full(n, 0.06)]])
    fan = [(3, 4, 5), (3, 5, 0), (3, 0, 1), (3, 1, 2)]  # the L is star-shaped from its inner corner
    triangles = [(c, b, a) for a, b, c in fan] + [(a + n, b + n, c + n) for a, b, c in fan]
    for i in range(n):
        j = (i + 1) % n
        triangles += [(i, j, j + n), (i, j + n, i + n)]
    return LinkMesh("l", vertices, np.array(triangles), "an L")


# --------------------------------------------------------------------------- the fitter


def test_fit_holds_every_point_of_a_box_surface_with_the_margin() -> None:
    mesh = box_mesh("box", (0.2, 0.08, 0.05), (0.01, -0.02, 0.03), np.eye(3), "a box")
    fit = fit_link(mesh, FAST)
    depth = inside_depth(surface_samples(mesh, 0.004), fit.bodies)
    assert np.min(depth) >= FAST.margin_m - 1e-9


@pytest.fixture(scope="module")
def l_fit():
    return fit_link(l_shape(), FAST)


def test_fit_holds_the_inside_of_a_solid_not_only_its_surface(l_fit) -> None:
    mesh, fit = l_shape(), l_fit
    lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    grid = np.stack(np.meshgrid(*[np.linspace(lo[i], hi[i], 18) for i in range(3)], indexing="ij"), -1).reshape(-1, 3)
    inside = grid[winding_numbers(grid, mesh.vertices, mesh.triangles) > 0.5]
    assert len(inside) > 100
    assert np.min(inside_depth(inside, fit.bodies)) >= FAST.margin_m - 1e-9


def test_an_l_shape_gets_several_capsules_that_hug_it_closer_than_one(l_fit) -> None:
    fit = l_fit
    one, *more = fit.tried_m
    assert len(fit.bodies) >= 2
    assert min(more) < one / 2
    assert fit.worst_over_approximation_m < 0.6 * one


def test_a_mesh_of_separate_parts_is_fitted_part_by_part_without_bridging_the_gap() -> None:
    near = box_mesh("two", (0.05, 0.05, 0.05), (0.0, 0.0, 0.0), np.eye(3), "near")
    far = box_mesh("two", (0.05, 0.05, 0.05), (0.3, 0.0, 0.0), np.eye(3), "far")
    mesh = merge_meshes("two", [near, far], "two boxes 0.25 m apart")
    fit = fit_link(mesh, FAST)
    assert np.min(inside_depth(surface_samples(mesh, 0.004), fit.bodies)) >= FAST.margin_m - 1e-9
    gap = np.array([[0.15, 0.0, 0.0]])
    assert inside_depth(gap, fit.bodies)[0] < 0  # nothing fitted between the boxes
    assert fit.worst_over_approximation_m < 0.03


def test_fit_is_deterministic_to_the_byte() -> None:
    from armwarden.robot.fitted_file import FittedGeometry

    mesh = box_mesh("box", (0.2, 0.08, 0.05), (0.01, -0.02, 0.03), np.eye(3), "a box")
    texts = [render_fitted(FittedGeometry("toy", {"repository": "here"}, FAST.margin_m, {"box": fit_link(mesh, FAST)}), ["toy"])
             for _ in range(2)]
    assert texts[0] == texts[1]


def test_turning_a_fit_half_a_turn_about_z_is_exact_and_holds_the_turned_mesh() -> None:
    mesh = box_mesh("box", (0.1, 0.04, 0.03), (0.02, 0.03, 0.01), np.eye(3), "a box")
    fit = fit_link(mesh, FAST)
    turn = np.diag([-1.0, -1.0, 1.0])
    turned = rotate_fit(fit, turn, "turned")
    assert [b.radius_m for b in turned.bodies] == [b.radius_m for b in fit.bodies]
    samples = surface_samples(mesh, 0.004) @ turn.T
    assert np.min(inside_depth(samples, turned.bodies)) >= FAST.margin_m - 1e-9


def test_turning_a_fit_by_an_odd_angle_grows_radii_by_the_rounding() -> None:
    mesh = box_mesh("box", (0.1, 0.04, 0.03), (0.02, 0.03, 0.01), np.eye(3), "a box")
    fit = fit_link(mesh, FAST)
    c, s = math.cos(0.3), math.sin(0.3)
    turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    turned = rotate_fit(fit, turn, "turned")
    samples = surface_samples(mesh, 0.004) @ turn.T
    assert np.min(inside_depth(samples, turned.bodies)) >= FAST.margin_m - 1e-9


def test_capsule_surface_points_lie_on_the_capsule() -> None:
    p0, p1 = np.array([0.0, 0.0, 0.0]), np.array([0.1, 0.05, 0.0])
    points = capsule_surface_points(p0, p1, 0.03, 0.005)
    assert np.allclose(point_segment_distances(points, p0, p1)[:, 0], 0.03)


def test_an_stl_file_is_read_into_vertices_and_triangles() -> None:
    pytest.importorskip("trimesh")  # the `fit` extra (also in `dev`)
    box = box_mesh("box", (0.2, 0.1, 0.05), (0.0, 0.0, 0.0), np.eye(3), "box")
    stl = b"\0" * 80 + struct.pack("<I", len(box.triangles))
    for tri in box.vertices[box.triangles]:
        stl += struct.pack("<12fH", 0.0, 0.0, 0.0, *tri.ravel(), 0)
    mesh = load_mesh("box", stl, "stl", "box.stl")
    assert len(mesh.triangles) == 12
    assert np.allclose(np.unique(mesh.vertices, axis=0), np.unique(box.vertices, axis=0), atol=1e-7)


def test_fitting_refuses_an_empty_mesh() -> None:
    pytest.importorskip("trimesh")
    with pytest.raises(FittingError):
        load_mesh("nothing", b"solid empty\nendsolid empty\n", "stl", "empty.stl")


def test_the_runtime_imports_do_not_load_trimesh() -> None:
    code = ("import sys, armwarden.robot, armwarden.robot.fitting, armwarden.robot.pairs; "
            "sys.exit(1 if 'trimesh' in sys.modules else 0)")
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    assert subprocess.run([sys.executable, "-c", code], env=env, check=False).returncode == 0


# --------------------------------------------------------------------------- the bundled FR3 file


@pytest.fixture(scope="module")
def fitted():
    return load_fitted(FITTED_PATH)


def test_the_bundled_file_fits_every_link_with_collision_geometry(fitted) -> None:
    arm = {f"fr3_link{i}" for i in range(8)}
    assert set(fitted.links) == arm | {"fr3_hand", "fr3_leftfinger", "fr3_rightfinger"}
    assert fitted.margin_m > 0
    for fit in fitted.links.values():
        assert fit.bodies and all(b.radius_m > fitted.margin_m for b in fit.bodies)
        assert len(fit.vertices_sha256) == 64


def test_the_bundled_file_names_its_source_and_licence() -> None:
    text = FITTED_PATH.read_text(encoding="utf-8")
    assert "github.com/frankaemika/franka_description" in text
    assert "Apache-2.0" in text
    assert "meshes/robot_arms/fr3/collision/link0.stl" in text


def test_the_bundled_file_is_exactly_what_the_renderer_writes(fitted) -> None:
    text = FITTED_PATH.read_text(encoding="utf-8")
    header = [line[2:] if line.startswith("# ") else line[1:] for line in text.splitlines() if line.startswith("#")]
    assert render_fitted(fitted, header) == text


def test_the_right_finger_is_the_left_finger_turned_half_a_turn(fitted) -> None:
    left, right = fitted.links["fr3_leftfinger"].bodies, fitted.links["fr3_rightfinger"].bodies
    assert len(left) == len(right)
    for a, b in zip(left, right, strict=True):
        assert b.p0_m == (-a.p0_m[0], -a.p0_m[1], a.p0_m[2])
        assert b.p1_m == (-a.p1_m[0], -a.p1_m[1], a.p1_m[2])
        assert b.radius_m == a.radius_m


def _cloud() -> dict[str, np.ndarray]:
    if not CLOUD_PATH.is_file():
        pytest.skip(f"no vertex cloud at {CLOUD_PATH}: make it with scripts/fit_geometry.py --vertices "
                    "(tests/robot/data/README.md)")
    with np.load(CLOUD_PATH) as data:
        return {name: data[name] for name in data.files}


@pytest.mark.parametrize("link", [f"fr3_link{i}" for i in range(8)] + ["fr3_hand", "fr3_leftfinger", "fr3_rightfinger"])
def test_every_collision_mesh_vertex_lies_inside_its_links_fitted_capsules(fitted, link: str) -> None:
    vertices = _cloud()[link]
    fit = fitted.links[link]
    assert hashlib.sha256(np.ascontiguousarray(vertices, dtype="<f4").tobytes()).hexdigest() == fit.vertices_sha256
    assert len(vertices) == fit.n_vertices
    depth = inside_depth(vertices.astype(float), fit.bodies)
    # the margin, less float32's rounding of the vertices (< 1e-7 m at these sizes)
    assert np.min(depth) >= fitted.margin_m - 1e-6, f"{link}: a vertex {-np.min(depth) + fitted.margin_m:.6f} m short"
