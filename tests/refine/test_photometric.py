"""Photometric refinement: a bumped plane seen by consistent views moves back to the true plane;
an exact mesh is not made worse; the refine_mesh stage writes the mesh and its scores."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import open3d as o3d
import pytest

from evdense.camera import Camera
from evdense.mesh.views import make_mesh, read_mesh, write_workspace
from evdense.poses import look_at
from evdense.refine.photometric import RefineConfig, refine_vertices, select_pairs
from evdense.refine.stage import run_refine
from evdense.testing.mesh_scenes import grid_plane, make_views, smooth_colour

CAM = Camera(80, 80, 70.0, 70.0, 39.5, 39.5)
EYES = [(0, 0, 2.5), (0.7, 0, 2.4), (-0.7, 0, 2.4), (0, 0.7, 2.4), (0, -0.7, 2.4)]


def texture(p: np.ndarray, n: np.ndarray) -> np.ndarray:
    return smooth_colour(p, n, freq=20.0)


@pytest.fixture(scope="module")
def plane():
    v, f = grid_plane(2.0, 24)
    poses = np.stack([look_at(np.array(e, float), np.zeros(3), up=(0.0, 1.0, 0.0)) for e in EYES])
    views = make_views(v, f, CAM, poses, texture)
    return v, f, views


def bumped(v: np.ndarray, seed: int = 0, noise: float = 0.01) -> np.ndarray:
    rng = np.random.default_rng(seed)
    out = v.copy()
    out[:, 2] += 0.08 * np.exp(-(v[:, :2] ** 2).sum(1) / 0.15) + rng.normal(
        scale=noise, size=len(v)
    )
    return out


INNER = lambda v: np.all(np.abs(v[:, :2]) < 0.7, axis=1)  # noqa: E731  (seen by every view)

FAST = RefineConfig(scales=[0.5, 1.0], iterations=30, max_seconds=60)


@pytest.mark.parametrize("regularizer", ["displacement", "surface"])
def test_refinement_moves_a_bumped_plane_to_the_true_plane(plane, regularizer):
    v, f, views = plane
    vb = bumped(v, noise=0.0)
    inner = INNER(v)
    conf = dataclasses.replace(FAST, regularizer=regularizer)
    res = refine_vertices(vb, f, views, conf, threads=1)
    before = np.abs(vb[inner, 2]).mean()
    after = np.abs(res.vertices[inner, 2]).mean()
    assert after < 0.1 * before
    assert np.abs(res.vertices[inner, 2]).max() < 0.1 * np.abs(vb[inner, 2]).max()
    assert res.score_output < res.score_input
    # Vertices move along their normals (nearly z here): x and y drift by far less than an edge (0.083).
    drift = np.linalg.norm(res.vertices[:, :2] - vb[:, :2], axis=1)
    assert drift.mean() < 0.005 and drift.max() < 0.04


def test_the_two_regularizers_on_vertex_noise(plane):
    """The bump plus 1 cm of noise per vertex (0.12 edge lengths): the surface regulariser smooths
    the noise away by itself; the displacement regulariser removes only what the images
    contradict, and does not round what they do not (the default: on the room scene's boxes it
    keeps edges that the surface regulariser wore down)."""
    v, f, views = plane
    vb = bumped(v, noise=0.01)
    inner = INNER(v)
    before = np.abs(vb[inner, 2]).mean()
    err = {}
    for reg in ("surface", "displacement"):
        res = refine_vertices(vb, f, views, dataclasses.replace(FAST, regularizer=reg), threads=1)
        assert res.score_output < res.score_input
        err[reg] = np.abs(res.vertices[inner, 2]).mean() / before
    assert err["surface"] < 0.1
    assert err["displacement"] < 0.5
    assert err["surface"] < err["displacement"]


def test_unknown_regularizer_is_refused(plane):
    v, f, views = plane
    with pytest.raises(ValueError, match="regularizer"):
        refine_vertices(v, f, views, RefineConfig(regularizer="thin-plate"), threads=1)


def test_refinement_never_returns_a_worse_mesh(plane):
    v, f, views = plane
    # The exact plane: nothing to gain; whatever the levels do, the output scores no worse.
    res = refine_vertices(
        v, f, views, RefineConfig(scales=[0.5], iterations=10, step=0.5), threads=1
    )
    assert res.score_output <= res.score_input
    if res.score_output == res.score_input:
        assert np.array_equal(res.vertices, v)
    assert np.abs(res.vertices[INNER(v), 2]).mean() < 0.01
    # No time: the input comes back unchanged.
    res = refine_vertices(v, f, views, RefineConfig(max_seconds=0.0), threads=1)
    assert np.array_equal(res.vertices, v) and res.score_levels == []


def test_pairs_respect_the_angle_range(plane):
    _, _, views = plane
    pairs = select_pairs(
        views, np.zeros(3), RefineConfig(min_angle=5.0, max_angle=40.0, pairs_per_view=2)
    )
    assert len(pairs) == 2 * len(views)
    assert all(i != j for i, j in pairs)
    assert select_pairs(views, np.zeros(3), RefineConfig(min_angle=60.0, max_angle=70.0)) == []


def test_refine_mesh_stage(tmp_path, plane):
    v, f, views = plane
    ws = tmp_path / "ws"
    write_workspace(ws, views)
    src = tmp_path / "mesh.ply"
    o3d.io.write_triangle_mesh(str(src), make_mesh(bumped(v, seed=1), f))
    out = run_refine(
        src,
        ws,
        tmp_path / "refined.ply",
        {"scales": [0.5], "iterations": 20},
        stats=tmp_path / "refined.json",
        threads=1,
    )
    stats = json.loads((tmp_path / "refined.json").read_text())
    assert stats["score_output"] <= stats["score_input"]
    r = np.asarray(read_mesh(out).vertices)
    assert (
        np.abs(r[INNER(v), 2]).mean()
        < np.abs(np.asarray(read_mesh(src).vertices)[INNER(v), 2]).mean()
    )
    with pytest.raises(ValueError, match="sparse"):
        run_refine(src, tmp_path, tmp_path / "x.ply")
