"""Cameras: projection round trips, distortion inversion, COLMAP pixel convention, file formats."""

from __future__ import annotations

import numpy as np
import pytest

from evdense.camera import Camera, davis346, load_camera


def test_rays_project_back_to_their_pixels():
    cam = Camera(40, 30, 35.0, 36.0, 19.2, 14.7, dist=(-0.23, 0.10, -0.002, 0.0036))
    rays = cam.pixel_rays().reshape(-1, 3)
    uv = cam.project(rays * 2.5)
    u, v = cam.pixel_grid()
    np.testing.assert_allclose(uv, np.c_[u.ravel(), v.ravel()], atol=1e-6)


def test_colmap_round_trip_shifts_principal_point(tmp_path):
    cam = Camera(346, 260, 250.0, 251.0, 172.5, 129.5)
    model, params = cam.colmap_model()
    assert model == "PINHOLE" and params[2:] == [173.0, 130.0]
    cam.write_colmap_cameras_txt(tmp_path / "cameras.txt")
    assert load_camera(tmp_path / "cameras.txt") == cam


def test_yaml_round_trip_and_real_davis_calibration(tmp_path, anchors):
    cam = davis346()
    cam.write_yaml(tmp_path / "intrinsics.yaml")
    assert load_camera(tmp_path / "intrinsics.yaml") == cam
    real = load_camera(anchors / "data" / "davis346_vins_calib.yaml")
    assert (real.width, real.height) == (346, 260)
    assert real.fx == pytest.approx(613.4558737183941)
    assert real.dist[0] == pytest.approx(-0.23012235846292012)


def test_unknown_calibration_names_the_file(tmp_path):
    p = tmp_path / "calib.yaml"
    p.write_text("foo: 1\n")
    with pytest.raises(ValueError, match="calib.yaml"):
        load_camera(p)
