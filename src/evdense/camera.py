"""Pinhole cameras with optional radial-tangential distortion, and their file formats.

Conventions: pixel centres at integer coordinates (the centre of the top-left pixel is (0, 0)),
camera frame x right, y down, z forward (OpenCV / COLMAP).
"""

from __future__ import annotations

import re
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import yaml


@dataclass(frozen=True)
class Camera:
    """A pinhole camera: image size in pixels, focal lengths and principal point in pixels.

    ``dist`` holds OpenCV radial-tangential coefficients ``(k1, k2, p1, p2)``; all zero means none.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    dist: tuple[float, float, float, float] = field(default=(0.0, 0.0, 0.0, 0.0))

    @property
    def K(self) -> np.ndarray:
        """The 3x3 intrinsic matrix."""
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1]], dtype=np.float64)

    @property
    def has_distortion(self) -> bool:
        return any(abs(d) > 0 for d in self.dist)

    def pixel_grid(self) -> tuple[np.ndarray, np.ndarray]:
        """Pixel centre coordinates ``(u, v)``, each ``(H, W)`` float64."""
        return np.meshgrid(
            np.arange(self.width, dtype=np.float64), np.arange(self.height, dtype=np.float64)
        )

    def distort(self, xn: np.ndarray, yn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Apply the distortion to normalised image coordinates (OpenCV model)."""
        k1, k2, p1, p2 = self.dist
        r2 = xn * xn + yn * yn
        radial = 1 + k1 * r2 + k2 * r2 * r2
        xd = xn * radial + 2 * p1 * xn * yn + p2 * (r2 + 2 * xn * xn)
        yd = yn * radial + p1 * (r2 + 2 * yn * yn) + 2 * p2 * xn * yn
        return xd, yd

    def undistort_normalized(
        self, xd: np.ndarray, yd: np.ndarray, iterations: int = 20
    ) -> tuple[np.ndarray, np.ndarray]:
        """Invert :meth:`distort` by fixed-point iteration (accurate to ~1e-9 for DAVIS lenses)."""
        if not self.has_distortion:
            return xd, yd
        xn, yn = xd.copy(), yd.copy()
        for _ in range(iterations):
            xe, ye = self.distort(xn, yn)
            xn = xn - (xe - xd)
            yn = yn - (ye - yd)
        return xn, yn

    def pixel_rays(self) -> np.ndarray:
        """Unit-depth ray directions in the camera frame for every pixel, ``(H, W, 3)``, z = 1."""
        u, v = self.pixel_grid()
        xd = (u - self.cx) / self.fx
        yd = (v - self.cy) / self.fy
        xn, yn = self.undistort_normalized(xd, yd)
        return np.stack([xn, yn, np.ones_like(xn)], axis=-1)

    def project(self, points_cam: np.ndarray) -> np.ndarray:
        """Project camera-frame points ``(N, 3)`` to pixels ``(N, 2)`` (distortion applied)."""
        z = points_cam[:, 2]
        xn, yn = points_cam[:, 0] / z, points_cam[:, 1] / z
        xd, yd = self.distort(xn, yn)
        return np.stack([self.fx * xd + self.cx, self.fy * yd + self.cy], axis=-1)

    def scaled(self, factor: float) -> Camera:
        """The same camera at ``factor`` times the resolution (for supersampling)."""
        return Camera(
            width=int(round(self.width * factor)),
            height=int(round(self.height * factor)),
            fx=self.fx * factor,
            fy=self.fy * factor,
            cx=(self.cx + 0.5) * factor - 0.5,
            cy=(self.cy + 0.5) * factor - 0.5,
            dist=self.dist,
        )

    # --- file formats -------------------------------------------------------------------
    def to_dict(self) -> dict:
        d = asdict(self)
        d["dist"] = list(self.dist)
        d["model"] = "OPENCV" if self.has_distortion else "PINHOLE"
        return d

    @classmethod
    def from_dict(cls, d: dict) -> Camera:
        return cls(
            width=int(d["width"]),
            height=int(d["height"]),
            fx=float(d["fx"]),
            fy=float(d["fy"]),
            cx=float(d["cx"]),
            cy=float(d["cy"]),
            dist=tuple(float(v) for v in d.get("dist", (0, 0, 0, 0))),  # type: ignore[arg-type]
        )

    def write_yaml(self, path: str | Path) -> None:
        """Write our intrinsics YAML (width, height, fx, fy, cx, cy, dist, model)."""
        Path(path).write_text(yaml.safe_dump(self.to_dict(), sort_keys=False))

    def colmap_model(self) -> tuple[str, list[float]]:
        """COLMAP camera model name and parameter list.

        COLMAP puts the centre of the top-left pixel at (0.5, 0.5), evdense at (0, 0): the
        principal point is shifted by +0.5 px here and by -0.5 px in :meth:`from_colmap`.
        """
        cx, cy = self.cx + 0.5, self.cy + 0.5
        if self.has_distortion:
            return "OPENCV", [self.fx, self.fy, cx, cy, *self.dist]
        return "PINHOLE", [self.fx, self.fy, cx, cy]

    @classmethod
    def from_colmap(cls, model: str, width: int, height: int, params: list[float]) -> Camera:
        """An evdense camera from COLMAP model parameters (principal point shifted by -0.5 px)."""
        p = [float(v) for v in params]
        w, h = int(width), int(height)
        if model == "PINHOLE":
            return cls(w, h, p[0], p[1], p[2] - 0.5, p[3] - 0.5)
        if model == "OPENCV":
            return cls(w, h, p[0], p[1], p[2] - 0.5, p[3] - 0.5, tuple(p[4:8]))  # type: ignore[arg-type]
        if model == "SIMPLE_PINHOLE":
            return cls(w, h, p[0], p[0], p[1] - 0.5, p[2] - 0.5)
        if model in ("SIMPLE_RADIAL", "RADIAL"):
            k2 = p[4] if model == "RADIAL" else 0.0
            return cls(w, h, p[0], p[0], p[1] - 0.5, p[2] - 0.5, (p[3], k2, 0.0, 0.0))
        raise ValueError(
            f"COLMAP camera model {model} is not supported (PINHOLE, OPENCV, SIMPLE_PINHOLE, SIMPLE_RADIAL, RADIAL)"
        )

    def write_colmap_cameras_txt(self, path: str | Path, camera_id: int = 1) -> None:
        """Write a COLMAP ``cameras.txt`` holding this one camera."""
        model, params = self.colmap_model()
        text = (
            "# Camera list with one line of data per camera:\n"
            "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
            f"# Number of cameras: 1\n"
            f"{camera_id} {model} {self.width} {self.height} "
            + " ".join(f"{p:.10g}" for p in params)
            + "\n"
        )
        Path(path).write_text(text)


def davis346() -> Camera:
    """Default DAVIS346 intrinsics (346x260), undistorted: a ~4.5 mm lens, ~70 deg horizontal FoV."""
    return Camera(width=346, height=260, fx=250.0, fy=250.0, cx=172.5, cy=129.5)


def load_camera(path: str | Path) -> Camera:
    """Read intrinsics from our YAML, a Kalibr/VINS YAML (``projection_parameters``), a COLMAP
    ``cameras.txt`` or an RPG ``calib.txt`` (``fx fy cx cy k1 k2 p1 p2 [k3]``; needs width and height
    elsewhere, so it is read by :func:`load_rpg_calib`).

    Raises ``ValueError`` naming the file when the format is not recognised.
    """
    path = Path(path)
    text = path.read_text()
    if path.suffix.lower() in (".yaml", ".yml"):
        # OpenCV's YAML writer starts with a %YAML:1.0 directive that PyYAML rejects.
        clean = re.sub(r"^%YAML[: ]?1\.0\s*\n", "", text)
        clean = re.sub(r"!!opencv-matrix", "", clean)
        d = yaml.safe_load(clean) or {}
        if "projection_parameters" in d:
            pp, dp = d["projection_parameters"], d.get("distortion_parameters", {}) or {}
            return Camera(
                width=int(d["image_width"]),
                height=int(d["image_height"]),
                fx=float(pp["fx"]),
                fy=float(pp["fy"]),
                cx=float(pp["cx"]),
                cy=float(pp["cy"]),
                dist=tuple(float(dp.get(k, 0.0)) for k in ("k1", "k2", "p1", "p2")),  # type: ignore[arg-type]
            )
        if {"width", "height", "fx", "fy", "cx", "cy"} <= set(d):
            return Camera.from_dict(d)
        raise ValueError(f"{path}: unrecognised calibration YAML (keys: {sorted(d)})")
    for line in text.splitlines():
        parts = line.split()
        if not parts or parts[0].startswith("#"):
            continue
        if len(parts) >= 5 and parts[1] in (
            "PINHOLE",
            "SIMPLE_PINHOLE",
            "OPENCV",
            "SIMPLE_RADIAL",
            "RADIAL",
        ):
            return Camera.from_colmap(
                parts[1], int(parts[2]), int(parts[3]), [float(v) for v in parts[4:]]
            )
        break
    raise ValueError(f"{path}: unrecognised calibration file")


def load_rpg_calib(path: str | Path, width: int, height: int) -> Camera:
    """Read an Event Camera Dataset ``calib.txt`` (one line: ``fx fy cx cy k1 k2 p1 p2 k3``)."""
    vals = [float(v) for v in Path(path).read_text().split()]
    if len(vals) < 4:
        raise ValueError(
            f"{path}: expected 'fx fy cx cy [k1 k2 p1 p2 k3]', found {len(vals)} numbers"
        )
    dist = tuple((vals[4:8] + [0.0] * 4)[:4])
    return Camera(width, height, vals[0], vals[1], vals[2], vals[3], dist)  # type: ignore[arg-type]
