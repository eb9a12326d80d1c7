"""Fitting capsules to a link mesh that is not convex: the fitter's signed depth with the grid's
signs (`SignedDistance`) against summing the winding number for every point, in one run.

The mesh is a torus built by trimesh (about the triangle count of a Kinova Gen3 link: no fetched
mesh is needed), or any STL/OBJ given with `--fit-mesh`; `--fit-bodies` capsules at most (the
time grows about with its square). Both fits must be identical: the grid only skips sums whose
sign it already knows."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from armwarden.robot import fitting_mesh
from armwarden.robot.fitting import FitOptions, fit_link
from armwarden.robot.fitting_mesh import LinkMesh, load_mesh


def _torus() -> LinkMesh:
    import trimesh  # pyright: ignore[reportMissingImports] - the `fit` extra

    torus = trimesh.creation.torus(major_radius=0.06, minor_radius=0.025, major_sections=120, minor_sections=40)
    return LinkMesh("torus", np.asarray(torus.vertices, dtype=float), np.asarray(torus.faces, dtype=np.int64),
                    "trimesh torus 0.06/0.025 m")


def _timed_fit(mesh: LinkMesh, options: FitOptions) -> tuple[float, Any]:
    start = time.perf_counter()
    fit = fit_link(mesh, options)
    return time.perf_counter() - start, fit


def bench_fit(mesh_path: str | None = None, bodies: int = 2) -> dict[str, Any]:
    if mesh_path is None:
        mesh = _torus()
    else:
        path = Path(mesh_path)
        mesh = load_mesh(path.stem, path.read_bytes(), path.suffix.lstrip(".").lower(), str(path))
    options = FitOptions(max_bodies=bodies)
    fit_link(LinkMesh("warm-up", mesh.vertices, mesh.triangles, mesh.source), FitOptions(max_bodies=1))  # compiles
    grid_s, grid_fit = _timed_fit(mesh, options)
    near_node = fitting_mesh.SignedDistance._near_node
    try:  # every point summed, as before the grid
        fitting_mesh.SignedDistance._near_node = lambda self, point, distance: None  # type: ignore[method-assign]
        summed_s, summed_fit = _timed_fit(mesh, options)
    finally:
        fitting_mesh.SignedDistance._near_node = near_node  # type: ignore[method-assign]
    return {"mesh": mesh.source, "triangles": len(mesh.triangles), "closed": fitting_mesh.is_closed(mesh.triangles),
            "max_bodies": bodies, "grid_s": grid_s, "summed_s": summed_s, "speedup": summed_s / grid_s,
            "identical": grid_fit == summed_fit, "worst_over_approximation_m": grid_fit.worst_over_approximation_m}


def report_fit(r: dict[str, Any]) -> None:
    print(f"\n== fit: {r['mesh']} ({r['triangles']} triangles, closed: {r['closed']}), up to {r['max_bodies']} capsules")
    print(f"grid signs {r['grid_s']:.1f} s, every point summed {r['summed_s']:.1f} s: {r['speedup']:.2f}x; "
          f"identical fits: {r['identical']} (worst over-approximation {r['worst_over_approximation_m'] * 1000:.1f} mm)")
