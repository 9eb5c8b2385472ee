"""Reading the dense workspace (cameras, poses, images) and writing meshes.

The dense workspace is COLMAP's undistorted layout, ``results/{dataset}/mvs/{source}/``:
``images/`` (undistorted frames), ``sparse/`` (pinhole cameras and registered poses, read with
``pycolmap.Reconstruction``) and ``fused.ply`` with ``fused.ply.vis`` (read with
:func:`evdense.formats.cloud.read_cloud`; an index in the visibility file is the position of the
image in ``Reconstruction.reg_image_ids()``, the order of :attr:`Views.names` here).
"""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import open3d as o3d

from evdense.camera import Camera
from evdense.formats.files import atomic_path


@dataclass
class Views:
    """Calibrated views: one camera, pose and image path per view.

    ``poses`` are camera-to-world ``(N, 4, 4)`` (x right, y down, z forward); images are read on
    demand with :meth:`image` as float32 in [0, 1], ``(H, W, C)`` with C = 1 or 3.
    """

    cameras: list[Camera]
    poses: np.ndarray
    image_paths: list[Path] = field(default_factory=list)
    names: list[str] = field(default_factory=list)
    images: list[np.ndarray] | None = None
    """Images held in memory (tests, benchmarks); when set, :meth:`image` returns them."""

    def __len__(self) -> int:
        return len(self.cameras)

    @property
    def centers(self) -> np.ndarray:
        """Camera centres in the world frame, ``(N, 3)`` metres."""
        return self.poses[:, :3, 3].copy()

    def image(self, i: int) -> np.ndarray:
        """Image ``i`` as float32 ``(H, W, C)`` in [0, 1] (C = 1 for grey, 3 for colour)."""
        if self.images is not None:
            img = np.asarray(self.images[i], dtype=np.float32)
        else:
            img = read_image(self.image_paths[i])
        if img.ndim == 2:
            img = img[..., None]
        cam = self.cameras[i]
        if img.shape[:2] != (cam.height, cam.width):
            raise ValueError(
                f"{self.names[i] if self.names else i}: image is {img.shape[1]}x{img.shape[0]}, "
                f"camera says {cam.width}x{cam.height}"
            )
        return img

    def subset(self, idx: list[int] | np.ndarray) -> Views:
        """The views at the given indices (same order)."""
        idx = [int(i) for i in idx]
        return Views(
            cameras=[self.cameras[i] for i in idx],
            poses=self.poses[idx],
            image_paths=[self.image_paths[i] for i in idx] if self.image_paths else [],
            names=[self.names[i] for i in idx] if self.names else [],
            images=[self.images[i] for i in idx] if self.images is not None else None,
        )

    def at_most(self, n: int) -> Views:
        """These views, or ``n`` of them spread evenly over the sequence when there are more."""
        if len(self) <= n:
            return self
        return self.subset(np.unique(np.linspace(0, len(self) - 1, n).round().astype(int)))


def read_image(path: str | Path) -> np.ndarray:
    """Read an 8- or 16-bit PNG/JPEG as float32 in [0, 1], ``(H, W)`` or ``(H, W, 3)`` (alpha dropped)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: image file not found")
    img = iio.imread(path)
    scale = 65535.0 if img.dtype == np.uint16 else 255.0
    img = img.astype(np.float32) / scale
    if img.ndim == 3 and img.shape[2] == 4:
        img = img[..., :3]
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[..., 0]
    return img


def read_views(workspace: str | Path) -> Views:
    """The registered views of a dense workspace (``sparse/`` and ``images/``), camera-to-world,
    as :func:`evdense.mvs.workspace.read_workspace` reads them (the one reader of a workspace).

    Raises ``ValueError`` naming the folder when ``sparse/`` is missing or holds no registered image.
    """
    from evdense.mvs.workspace import read_workspace

    ws = read_workspace(workspace, points=False, require_pinhole=False)
    return Views(
        cameras=[im.camera for im in ws.images],
        poses=np.stack([im.T_wc for im in ws.images]),
        image_paths=[ws.image_path(im.name) for im in ws.images],
        names=[im.name for im in ws.images],
    )


def write_workspace(workspace: str | Path, views: Views) -> None:
    """Write ``views`` (with in-memory images) as a dense workspace: ``images/*.png`` and ``sparse/``.

    Used by tests and benchmarks to stand in for the MVS stage's output.
    """
    import pycolmap

    workspace = Path(workspace)
    (workspace / "images").mkdir(parents=True, exist_ok=True)
    (workspace / "sparse").mkdir(parents=True, exist_ok=True)
    rec = pycolmap.Reconstruction()
    for i, cam in enumerate(views.cameras):
        model, params = cam.colmap_model()
        rec.add_camera_with_trivial_rig(
            pycolmap.Camera(
                camera_id=i + 1, model=model, width=cam.width, height=cam.height, params=params
            )
        )
        name = views.names[i] if views.names else f"{i:06d}.png"
        img = views.image(i)
        write_png(workspace / "images" / name, img)
        T_cw = np.linalg.inv(views.poses[i])
        im = pycolmap.Image(name=name, camera_id=i + 1, image_id=i + 1)
        rec.add_image_with_trivial_frame(
            im, pycolmap.Rigid3d(pycolmap.Rotation3d(T_cw[:3, :3]), T_cw[:3, 3].copy())
        )
    rec.write(str(workspace / "sparse"))


def write_png(path: str | Path, img: np.ndarray) -> None:
    """Write a float image in [0, 1] (``(H, W)`` or ``(H, W, C)``, C in 1, 3) as an 8-bit PNG."""
    img = np.asarray(img)
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[..., 0]
    iio.imwrite(path, np.clip(np.rint(img * 255.0), 0, 255).astype(np.uint8))


def read_mesh(path: str | Path) -> o3d.geometry.TriangleMesh:
    """Read a triangle mesh; raises ``ValueError`` naming the file when missing or without faces."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: mesh file not found")
    mesh = o3d.io.read_triangle_mesh(str(path))
    if len(mesh.triangles) == 0:
        raise ValueError(f"{path}: no triangles in the mesh")
    return mesh


def make_mesh(vertices: np.ndarray, faces: np.ndarray) -> o3d.geometry.TriangleMesh:
    """An open3d mesh from ``vertices (V, 3)`` and ``faces (F, 3)``."""
    return o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(np.asarray(vertices, dtype=np.float64)),
        o3d.utility.Vector3iVector(np.asarray(faces, dtype=np.int32)),
    )


def write_mesh(path: str | Path, mesh: o3d.geometry.TriangleMesh) -> Path:
    """Write a mesh atomically (a temporary name in the same folder, then rename); returns the path."""
    path = Path(path)
    with atomic_path(path, keep_suffix=True) as tmp:
        if not o3d.io.write_triangle_mesh(str(tmp), mesh, write_ascii=False):
            raise ValueError(f"{path}: open3d could not write the mesh")
    return path


def replace_dir(tmp: Path, final: Path) -> None:
    """Move a finished temporary folder onto ``final`` (removing an older one)."""
    if final.exists():
        shutil.rmtree(final)
    os.replace(tmp, final)
