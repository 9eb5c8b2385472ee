"""Training data for intensity reconstruction, made by our own simulator and cached in one HDF5.

Every sequence is a small random scene (:mod:`evdense.sim.scene`: textured planes, boxes,
cylinders, an optional light surface for HDR), rendered by :class:`evdense.sim.render.Renderer`
along a random bounded 6-DoF motion and turned into events by the ESIM-style simulator
(:func:`evdense.sim.esim.simulate_event_stream`) with random contrast thresholds, background
noise and hot pixels. The stream is cut into windows of ``N`` events (``N`` = events per pixel
times the pixel count, as at inference), each window becomes a B-bin voxel grid
(:func:`evdense.events.voxel.voxel_grid`, stored raw), and the scene is rendered again at the
last event of each window to give the target.

Target (what our network predicts): the log radiance at the window's end, mapped to [0, 1] by the
robust range of the whole sequence, ``clip((log R - q_lo) / (q_hi - q_lo), 0, 1)`` with ``q_lo``,
``q_hi`` the ``target_percentiles`` of ``log R`` over all the sequence's targets. This is the log
tone-mapping of our GT frames (:func:`evdense.sim.groundtruth.tonemap_log`): an HDR scene keeps
detail in its dark and bright parts (what SfM features need), and events, which see only log
changes, determine it up to an offset and a scale.

Splits (``split`` argument; the held-out one never shares textures, object kinds or motions with
training):

- ``train`` / ``val``: procedural textures (dead leaves, spectral noise) and the natural images of
  :data:`TRAIN_IMAGES`, planes and boxes, smooth random motion, some HDR light panels. ``val``
  differs from ``train`` only by its seed (used to pick the best checkpoint).
- ``heldout``: checkerboards, noise with variation and the images of :data:`HELDOUT_IMAGES`,
  cylinders and a floor, and three motion families training never saw: ``fast`` (4x faster),
  ``shake`` (high-frequency rotation), ``hdr`` (a bright light panel, dynamic range 20-100).

HDF5 layout (``format`` attribute ``evdense-recon-trainset``)::

    /seq_00000/voxels   (W, B, H, Wd) float16  raw voxel grids of the W windows
    /seq_00000/targets  (W, H, Wd)    float16  targets in [0, 1] (see above)
    /seq_00000/t_end_us (W,)          int64    last event time of each window
    /seq_00000/log_radiance_range (2,) float64 q_lo, q_hi
    /seq_00000/events/{t,x,y,p}, /seq_00000/window_index (W + 1,)   (only when store_events)
    seq attrs: recipe JSON (scene spec, motion, event camera settings, events per pixel)
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable, Iterator
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import h5py
import numpy as np
from scipy.spatial.transform import Rotation

from evdense.events.container import Events
from evdense.events.voxel import voxel_grid
from evdense.log import get_logger, progress
from evdense.sim.esim import EventCameraConfig, simulate_event_stream
from evdense.sim.render import RenderConfig, Renderer
from evdense.sim.scene import build_scene
from evdense.training.planar import TEXTURE_KINDS, TRAIN_PICTURES, PlanarConfig, find_pictures

log = get_logger("training")

TRAINSET_FORMAT = "evdense-recon-trainset"
TRAINSET_VERSION = 2
SPLITS = ("train", "val", "heldout")

TRAIN_IMAGES = (
    "astronaut",
    "brick",
    "camera",
    "chelsea",
    "coffee",
    "grass",
    "gravel",
    "rocket",
    "hubble_deep_field",
    "retina",
)
"""skimage.data pictures used as textures in training (and val)."""
HELDOUT_IMAGES = ("moon", "text", "coins", "page", "cell", "immunohistochemistry")
"""skimage.data pictures used only in the held-out sequences."""


@dataclass
class TrainDataConfig:
    """Recipe of a simulated training set (config section ``train.data``)."""

    width: int = 128
    """Camera width, pixels."""
    height: int = 96
    """Camera height, pixels."""
    focal_px: float = 100.0
    """Focal length, pixels (about 65 degrees horizontal field of view at 128 px)."""
    bins: int = 5
    """Temporal bins B of the voxel grids."""
    windows_per_sequence: int = 48
    """Windows of N events simulated per train/val sequence."""
    heldout_windows_per_sequence: int = 32
    """Windows of N events per held-out sequence."""
    planar_fraction: float = 0.7
    """Fraction of train/val sequences from the planar generator (textured layers sliding over each
    other, src/evdense/training/planar.py); the rest are 3D scenes."""
    events_per_pixel: list[float] = field(default_factory=lambda: [0.15, 0.8])
    """Range [lo, hi] of events per pixel in a window (N = value x width x height), drawn log-uniform per sequence."""
    heldout_events_per_pixel: float = 0.3
    """Events per pixel in the windows of the held-out split (the pipeline's default is ~0.28)."""
    contrast_range: list[float] = field(default_factory=lambda: [0.1, 1.2])
    """Range of the mean contrast threshold C (log units), drawn log-uniform per sequence."""
    contrast_asymmetry: float = 1.5
    """Largest ratio between the ON and OFF thresholds (each drawn as C * r^(+-1), r in [1, this])."""
    contrast_spread: list[float] = field(default_factory=lambda: [0.03, 0.3])
    """Range of the per-pixel threshold spread as a fraction of C (Gaussian sigma), drawn uniform."""
    refractory_us: list[float] = field(default_factory=lambda: [0.0, 1000.0])
    """Range of the refractory period, microseconds, drawn uniform."""
    cutoff_hz: list[float] = field(default_factory=lambda: [0.0, 0.0])
    """Range [lo, hi] of the pixels' cut-off frequency at full brightness (Hz, the event camera's
    ``cutoff_hz``), drawn log-uniform per train/val sequence from a generator of its own (the
    other draws of a seed stay as they are). [0, 0] leaves the pixels' bandwidth unlimited."""
    noise_rate_range: list[float] = field(default_factory=lambda: [0.01, 5.0])
    """Range of background-activity noise per pixel (Hz), drawn log-uniform."""
    hot_pixel_fraction_max: float = 1e-3
    """Largest fraction of hot pixels (drawn uniform in [0, this])."""
    step_tolerance: float = 0.5
    """ESIM adaptive step: largest log change between renders as a fraction of C."""
    target_percentiles: list[float] = field(default_factory=lambda: [0.5, 99.5])
    """Percentiles of a sequence's log radiance mapped to target 0 and 1."""
    hdr_fraction: float = 0.3
    """Fraction of train/val sequences with a lit region or light panel."""
    dynamic_range_max: float = 1e5
    """Largest dynamic range (lit / unlit radiance) of those, drawn log-uniform from 2 (3D) or 10 (planar)."""
    max_duration_s: float = 30.0
    """Give up on a sequence whose windows are not complete after this many seconds of motion."""
    max_renders: int = 6000
    """Give up on a sequence whose windows are not complete after this many renders (bounds the cost of one sequence)."""
    texture_size: int = 512
    """Side of the procedural textures, texels."""
    planar_textures: dict[str, float] = field(
        default_factory=lambda: dict(PlanarConfig().texture_weights)
    )
    """Relative frequency of each texture kind of the planar generator (picture, dead_leaves, noise,
    flat, shapes, text, grating, mosaic; a kind left out is not drawn). The default leaves out
    mosaic (textured dead leaves filled from the other kinds)."""
    picture_dirs: list[str] = field(default_factory=list)
    """Folders whose images (.jpg, .jpeg, .png, found recursively, in sorted order) join the
    planar generator's built-in pictures for its ``picture`` kind and the mosaic's fills. Relative
    paths are from the working directory (the repository root for the workflow's train rule); a
    folder that is missing or holds no image is an error. The set records the folders, not their
    content: rebuild a pool elsewhere and the same seed may draw other pictures.
    Default: none, only the pictures scikit-image and Matplotlib install.
    ``benchmarks/make_picture_pool.sh`` makes one from Debian packages."""
    low_contrast_fraction: float = 0.0
    """Fraction of the 3D scenes' surface textures (train and val) drawn with a low contrast: mean
    level log-uniform in [0.03, 0.8], high / low ratio log-uniform in [1.05, 3] (plain or faintly
    textured walls), instead of low 0.02-0.15 and high 0.55-1.0. At 0 no random draw is added."""

    room_fraction: float = 0.0
    """Fraction of train/val sequences that are rooms (:func:`random_room_spec`): the camera inside
    a box of floor, ceiling and four walls at unrelated levels, most of them plain, turned so that
    corners and floor come into view, with a few boxes; the others come from the planar generator
    or the 3D scenes as before. Drawn per sequence from a generator of its own, so the sequences
    that are not rooms are those of the same seed without rooms. 0 makes none."""

    def check(self) -> None:
        if not 0.0 <= self.room_fraction <= 1.0:
            raise ValueError(
                f"train.data.room_fraction must lie in [0, 1], not {self.room_fraction}"
            )
        unknown = sorted(set(self.planar_textures) - set(TEXTURE_KINDS))
        if unknown:
            raise ValueError(f"train.data.planar_textures: unknown kinds {unknown} "
                             f"(known: {list(TEXTURE_KINDS)})")  # fmt: skip
        w = list(self.planar_textures.values())
        if any(not v >= 0 for v in w) or not sum(w) > 0:
            raise ValueError("train.data.planar_textures: weights must be >= 0 with a positive sum, "
                             f"not {self.planar_textures}")  # fmt: skip
        lo, hi = self.cutoff_hz
        if not (lo == hi == 0 or 0 < lo <= hi):
            raise ValueError(
                f"train.data.cutoff_hz must be [0, 0] or 0 < lo <= hi, not {self.cutoff_hz}"
            )
        find_pictures(tuple(self.picture_dirs))  # a missing or empty folder fails before simulating


HELDOUT_RECIPE = {
    "contrast_range": [0.1, 0.8],
    "contrast_asymmetry": 1.25,
    "noise_rate_range": [0.01, 2.0],
    "hot_pixel_fraction_max": 1e-3,
    "step_tolerance": 0.3,
    "target_percentiles": [0.5, 99.5],
    "max_duration_s": 8.0,
    "max_renders": 10**9,
    "cutoff_hz": [0.0, 0.0],
    "room_fraction": 0.0,
}
"""The held-out split's fixed recipe (independent of the training recipe, so that every model is
scored on the same sequences): 3D scenes with the held-out textures, objects and motions."""


def _loguniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


# ---------------------------------------------------------------------------------------------
# Random scenes
# ---------------------------------------------------------------------------------------------


def _random_texture(
    rng: np.random.Generator, split: str, size: int, low_contrast: float = 0.0
) -> dict:
    low = float(rng.uniform(0.02, 0.15))
    high = float(rng.uniform(0.55, 1.0))
    seed = int(rng.integers(0, 2**31))
    if split != "heldout" and low_contrast > 0 and rng.random() < low_contrast:
        mean, ratio = _loguniform(rng, 0.03, 0.8), _loguniform(rng, 1.05, 3.0)
        low, high = mean / np.sqrt(ratio), min(1.0, mean * np.sqrt(ratio))
    if split == "heldout":
        kind = rng.choice(["checker", "noise_var", "image", "image"])
        if kind == "checker":
            sq = int(rng.choice([4, 8, 16]))
            return {"type": "checker", "size": 256, "squares": sq, "low": low, "high": high}
        if kind == "noise_var":
            return {
                "type": "noise", "size": size, "beta": float(rng.uniform(2.0, 3.0)),
                "sharpness": float(rng.uniform(2.0, 4.0)), "variation": 0.5,
                "low": low, "high": high, "seed": seed,
            }  # fmt: skip
        return {"type": "image", "path": "skimage:" + str(rng.choice(HELDOUT_IMAGES)), "low": low,
                "high": high}  # fmt: skip
    kind = rng.choice(["dead_leaves", "noise", "image"], p=[0.35, 0.25, 0.4])
    if kind == "dead_leaves":
        return {
            "type": "dead_leaves", "size": size, "rmin": float(rng.uniform(1.5, 4.0)),
            "rmax": float(rng.uniform(30, 160)), "alpha": float(rng.uniform(2.5, 3.5)),
            "low": low, "high": high, "seed": seed,
        }  # fmt: skip
    if kind == "noise":
        return {
            "type": "noise", "size": size, "beta": float(rng.uniform(1.8, 3.2)),
            "sharpness": float(rng.uniform(0.8, 2.5)), "low": low, "high": high, "seed": seed,
        }  # fmt: skip
    return {"type": "image", "path": "skimage:" + str(rng.choice(TRAIN_IMAGES)), "low": low,
            "high": high}  # fmt: skip


def _light_material(rng: np.random.Generator) -> dict:
    """A light panel's material (radiance times the dataset's dynamic range, unshaded)."""
    return {
        "texture": {"type": "noise", "size": 128, "beta": 3.0, "low": 0.6, "high": 1.0,
                    "seed": int(rng.integers(0, 2**31))},
        "tile_m": 1.0, "radiance": 1.0, "light": True,
    }  # fmt: skip


def _scene_dict(name: str, rng: np.random.Generator, materials: dict, objects: list[dict]) -> dict:
    """A scene spec of these materials and objects under a random directional shading."""
    return {
        "name": name,
        "duration": 1.0,
        "shading": {"direction": rng.normal(0, 1, 3).tolist(), "ambient": float(rng.uniform(0.3, 0.8))},
        "materials": materials,
        "objects": objects,
        # unused (we pass our own poses), but a scene needs one
        "trajectory": {"type": "spline", "key_poses": [
            {"position": [0, 0, 0], "look_at": [0, 0, 1]},
            {"position": [0.1, 0, 0], "look_at": [0.1, 0, 1]}]},
    }  # fmt: skip


def random_scene_spec(
    rng: np.random.Generator, split: str, hdr: bool, size: int = 512, low_contrast: float = 0.0
) -> dict:
    """A random scene spec (see :mod:`evdense.sim.scene`) in front of a camera at the origin.

    The camera looks along +z (world = initial camera frame, metres). A large back plane at 1.5 to
    4 m fills the view; boxes (train) or boxes, cylinders and a floor (held-out) stand in front of
    it; with ``hdr`` a light panel (radiance times the dataset's dynamic range) is added.
    ``low_contrast``: the fraction of train/val textures drawn with a low contrast
    (:attr:`TrainDataConfig.low_contrast_fraction`).
    """
    depth = float(rng.uniform(1.5, 4.0))
    tilt = Rotation.from_rotvec(rng.normal(0, 0.3, 3) * np.array([1, 1, 0.2]))
    normal = tilt.apply([0.0, 0.0, -1.0])
    up = tilt.apply([0.0, -1.0, 0.0])
    materials: dict[str, Any] = {
        "back": {
            "texture": _random_texture(rng, split, size, low_contrast),
            "tile_m": float(rng.uniform(0.8, 4)),
        }
    }
    objects: list[dict] = [
        {"type": "plane", "center": [0.0, 0.0, depth], "size": [40.0, 40.0],
         "normal": normal.tolist(), "up": up.tolist(), "material": "back"}
    ]  # fmt: skip
    n_obj = int(rng.integers(0, 4))
    for i in range(n_obj):
        name = f"obj{i}"
        materials[name] = {
            "texture": _random_texture(rng, split, size, low_contrast),
            "tile_m": float(rng.uniform(0.3, 1.5)),
        }
        z = float(rng.uniform(0.9, depth - 0.3))
        x, y = rng.uniform(-0.45, 0.45, 2) * z
        s = float(rng.uniform(0.15, 0.5)) * z
        if split == "heldout" and rng.random() < 0.6:
            objects.append({"type": "cylinder", "center": [float(x), float(y), z],
                            "radius": s / 2, "height": s * 1.5,
                            "rotation_deg": rng.uniform(-90, 90, 3).tolist(), "material": name})  # fmt: skip
        else:
            objects.append({"type": "box", "size": (s * rng.uniform(0.5, 1.5, 3)).tolist(),
                            "center": [float(x), float(y), z],
                            "rotation_deg": rng.uniform(-60, 60, 3).tolist(), "material": name})  # fmt: skip
    if split == "heldout" and rng.random() < 0.5:
        materials["floor"] = {"texture": _random_texture(rng, split, size), "tile_m": 2.0}
        objects.append({"type": "plane", "center": [0.0, 1.0, depth / 2], "size": [14.0, 14.0],
                        "normal": [0.0, -1.0, 0.0], "up": [0.0, 0.0, 1.0], "material": "floor"})  # fmt: skip
    if hdr:
        materials["light"] = _light_material(rng)
        c = tilt.apply(
            [float(rng.uniform(-0.4, 0.4)) * depth, float(rng.uniform(-0.3, 0.3)) * depth, 0]
        )
        w = float(rng.uniform(0.2, 0.5)) * depth
        objects.append({"type": "plane", "center": (c + [0, 0, depth - 0.02]).tolist(),
                        "size": [w, w * float(rng.uniform(0.5, 1.5))], "normal": normal.tolist(),
                        "up": up.tolist(), "material": "light"})  # fmt: skip
    return _scene_dict("train_scene", rng, materials, objects)


ROOM_PLAIN_FRACTION = 0.6
"""Share of a room's surfaces drawn plain or faintly textured (the low-contrast draw of
:attr:`TrainDataConfig.low_contrast_fraction`); the others get the 3D scenes' textures."""


def random_room_spec(rng: np.random.Generator, hdr: bool, size: int = 512) -> dict:
    """A random room around a camera at the origin (train/val only; see ``random_scene_spec``).

    A box 2.5-6 m wide, 3-7 m deep and 2.2-3.2 m high, seen from inside: the camera stands 0.8 m
    or more from the floor and the side and rear walls, 0.6 m or more from the ceiling (all beyond
    the reach of :func:`random_motion`), 1.5 m or more from the wall ahead, and the room is turned
    by up to 45 degrees of yaw and 30 of pitch, so that walls meet in corners, floor and ceiling
    in the view. Each of the six surfaces has a material of its
    own, plain with probability :data:`ROOM_PLAIN_FRACTION`; the directional shading gives the
    surfaces of one material different levels. 0-3 textured boxes stand in front of the camera;
    with ``hdr`` a light panel (a window) is set in the wall ahead.
    """
    width, depth, height = rng.uniform(2.5, 6.0), rng.uniform(3.0, 7.0), rng.uniform(2.2, 3.2)
    ahead = rng.uniform(1.5, depth - 0.8)  # camera to the wall ahead
    eye = rng.uniform(0.8, height - 0.6)  # camera above the floor
    # room frame: x right, y ahead, z up; camera frame: x right, y down, z ahead
    turn = Rotation.from_euler(
        "yx", [rng.uniform(-45, 45), rng.uniform(-30, 30)], degrees=True
    ) * Rotation.from_euler("x", 90, degrees=True)
    centre = np.array([rng.uniform(-0.3, 0.3) * (width - 1.6), ahead - depth / 2, height / 2 - eye])
    faces = ("right", "left", "back", "front", "top", "bottom")
    materials: dict[str, Any] = {
        f"room_{f}": {
            "texture": _random_texture(rng, "train", size, ROOM_PLAIN_FRACTION),
            "tile_m": float(rng.uniform(0.5, 3.0)),
        }
        for f in faces
    }
    objects: list[dict] = [
        {"type": "room", "size": [float(width), float(depth), float(height)],
         "center": turn.apply(centre).tolist(),
         "rotation_deg": turn.as_euler("xyz", degrees=True).tolist(),
         "face_materials": {f: f"room_{f}" for f in faces}}
    ]  # fmt: skip
    for i in range(int(rng.integers(0, 4))):
        materials[f"obj{i}"] = {
            "texture": _random_texture(rng, "train", size),
            "tile_m": float(rng.uniform(0.3, 1.5)),
        }
        z = float(rng.uniform(0.9, max(1.0, ahead - 0.3)))
        x, y = rng.uniform(-0.45, 0.45, 2) * z
        s = float(rng.uniform(0.1, 0.3)) * z  # smaller than the 3D scenes': the walls lead
        objects.append({"type": "box", "size": (s * rng.uniform(0.5, 1.5, 3)).tolist(),
                        "center": [float(x), float(y), z],
                        "rotation_deg": rng.uniform(-60, 60, 3).tolist(), "material": f"obj{i}"})  # fmt: skip
    if hdr:
        materials["light"] = _light_material(rng)
        w = float(rng.uniform(0.2, 0.5)) * min(width, height)
        at = centre + [
            rng.uniform(-0.3, 0.3) * width,
            depth / 2 - 0.02,
            rng.uniform(-0.2, 0.2) * height,
        ]
        objects.append({"type": "plane", "center": turn.apply(at).tolist(),
                        "size": [w, w * float(rng.uniform(0.5, 1.5))],
                        "normal": turn.apply([0.0, -1.0, 0.0]).tolist(),
                        "up": turn.apply([0.0, 0.0, 1.0]).tolist(), "material": "light"})  # fmt: skip
    return _scene_dict("train_room", rng, materials, objects)


# ---------------------------------------------------------------------------------------------
# Random bounded 6-DoF motion
# ---------------------------------------------------------------------------------------------


@dataclass
class Motion:
    """Bounded smooth 6-DoF motion: each rotation-vector and position component is a sum of sinusoids."""

    rot_amp: np.ndarray
    """(K, 3) amplitudes of the rotation vector, radians."""
    pos_amp: np.ndarray
    """(K, 3) amplitudes of the position, metres."""
    freq: np.ndarray
    """(K, 6) frequencies, Hz."""
    phase: np.ndarray
    """(K, 6) phases, radians."""

    def pose(self, t: float) -> np.ndarray:
        """Camera-to-world pose ``(4, 4)`` at time ``t`` (seconds)."""
        s = np.sin(2 * np.pi * self.freq * t + self.phase) - np.sin(self.phase)  # 0 at t = 0
        rv = (self.rot_amp * s[:, :3]).sum(0)
        T = np.eye(4)
        T[:3, :3] = Rotation.from_rotvec(rv).as_matrix()
        T[:3, 3] = (self.pos_amp * s[:, 3:]).sum(0)
        return T

    def to_dict(self) -> dict[str, Any]:
        return {k: np.asarray(v).tolist() for k, v in asdict(self).items()}


def random_motion(rng: np.random.Generator, kind: str) -> Motion:
    """Random motion of a family: ``smooth`` (train/val), ``fast`` (4x faster), ``shake`` (5-12 Hz rotation)."""
    k = 3
    rot_amp = rng.normal(0, 1, (k, 3)) * np.array([0.08, 0.08, 0.05])
    pos_amp = rng.normal(0, 1, (k, 3)) * np.array([0.15, 0.1, 0.15])
    freq = rng.uniform(0.2, 1.5, (k, 6))
    if kind == "fast":
        freq *= 4.0
    elif kind == "shake":
        freq[:, :3] = rng.uniform(5.0, 12.0, (k, 3))
        rot_amp *= 0.25
        pos_amp *= 0.2
    elif kind != "smooth":
        raise ValueError(f"unknown motion kind {kind!r} (smooth, fast, shake)")
    phase = rng.uniform(0, 2 * np.pi, (k, 6))
    return Motion(rot_amp, pos_amp, freq, phase)


# ---------------------------------------------------------------------------------------------
# One sequence
# ---------------------------------------------------------------------------------------------


class _Enough(Exception):
    """Raised by the event sink to stop the simulation once enough events were made."""


class _TooSlow(Exception):
    """Raised by the renderer wrapper when a sequence needs more than ``max_renders`` renders."""


@dataclass
class Sequence:
    """One simulated sequence: windows of events, their raw voxel grids and targets."""

    voxels: np.ndarray
    """(W, B, H, Wd) float32 raw voxel grids."""
    targets: np.ndarray
    """(W, H, Wd) float32 targets in [0, 1]."""
    log_radiance: np.ndarray
    """(W, H, Wd) float32 log radiance at the window ends (the GT before normalisation)."""
    t_end_us: np.ndarray
    """(W,) int64 time of the last event of each window, microseconds."""
    window_index: np.ndarray
    """(W + 1,) int64 event index where each window starts (last entry: end of the last)."""
    events: Events
    """All events of the windows."""
    log_range: tuple[float, float]
    """q_lo, q_hi: log radiance mapped to target 0 and 1."""
    recipe: dict[str, Any]
    """Scene spec, motion, event camera settings, events per pixel, kind."""


def _event_camera(conf: TrainDataConfig, split: str, rng: np.random.Generator) -> EventCameraConfig:
    """Event camera settings drawn for one sequence (the held-out split keeps its fixed recipe)."""
    c = _loguniform(rng, *conf.contrast_range)
    r = float(rng.uniform(1.0, conf.contrast_asymmetry)) ** float(rng.choice([-1, 1]))
    if split == "heldout":
        spread, refractory = 0.1, 100.0
    else:
        spread = float(rng.uniform(*conf.contrast_spread))
        refractory = float(rng.uniform(*conf.refractory_us))
    return EventCameraConfig(
        contrast_pos=c * r,
        contrast_neg=c / r,
        contrast_sigma=spread * c,
        contrast_min=0.05,
        refractory_us=refractory,
        noise_rate_hz=_loguniform(rng, *conf.noise_rate_range),
        hot_pixel_fraction=float(rng.uniform(0, conf.hot_pixel_fraction_max)),
        hot_pixel_rate_hz=float(rng.uniform(10, 100)),
        step_tolerance=conf.step_tolerance,
        max_step_us=2000.0,
        chunk_events=1024,
    )


def _sequence_recipe(
    conf: TrainDataConfig, split: str, rng: np.random.Generator, room: bool = False
) -> tuple[dict, Motion, EventCameraConfig, int, dict[str, Any]]:
    if split == "heldout":
        kind = str(rng.choice(["fast", "shake", "hdr", "smooth"]))
    else:
        kind = "hdr" if rng.random() < conf.hdr_fraction else "smooth"
    hdr = kind == "hdr"
    if room:
        spec = random_room_spec(rng, hdr, conf.texture_size)
    else:
        spec = random_scene_spec(rng, split, hdr, conf.texture_size, conf.low_contrast_fraction)
    if split == "heldout":
        dyn = _loguniform(rng, 20.0, 100.0) if hdr else 1.0
    else:
        dyn = _loguniform(rng, 2.0, conf.dynamic_range_max) if hdr else 1.0
    motion = random_motion(rng, "smooth" if kind == "hdr" else kind)
    cam = _event_camera(conf, split, rng)
    n, epp = _window_size(conf, split, rng)
    info = {"kind": kind, "dynamic_range": dyn, "events_per_pixel": epp, "events_per_window": n}
    if room:
        info["room"] = True
    return spec, motion, cam, n, info


def _window_size(conf: TrainDataConfig, split: str, rng: np.random.Generator) -> tuple[int, float]:
    if split == "heldout":
        epp = conf.heldout_events_per_pixel
    else:
        epp = _loguniform(rng, *conf.events_per_pixel)
    return max(1, int(round(epp * conf.width * conf.height))), epp


def heldout_config(conf: TrainDataConfig) -> TrainDataConfig:
    """``conf`` with the held-out split's fixed recipe (:data:`HELDOUT_RECIPE`)."""
    return TrainDataConfig(
        **{
            **asdict(conf),
            **HELDOUT_RECIPE,
            "windows_per_sequence": conf.heldout_windows_per_sequence,
        }
    )


def simulate_sequence(conf: TrainDataConfig, split: str, seed: int) -> Sequence | None:
    """Simulate one random sequence of ``split`` from ``seed``; None when it makes too few events.

    Returns ``conf.windows_per_sequence`` windows of N events, their raw voxel grids ``(B, H, W)``
    and targets ``(H, W)`` (see the module docstring). Train and val sequences come from the
    planar generator with probability ``conf.planar_fraction``, else from a 3D scene; held-out
    sequences always from a held-out 3D scene, with :data:`HELDOUT_RECIPE`.
    """
    if split not in SPLITS:
        raise ValueError(f"unknown split {split!r} ({', '.join(SPLITS)})")
    if split == "heldout":
        conf = heldout_config(conf)
    rng = np.random.default_rng(seed)
    room = conf.room_fraction > 0 and np.random.default_rng([seed, 2]).random() < conf.room_fraction
    if split != "heldout" and not room and rng.random() < conf.planar_fraction:
        radiance_at, cam, n, recipe_extra = _planar_recipe(conf, split, rng)
    else:
        spec, motion, cam, n, info = _sequence_recipe(conf, split, rng, room)
        render = RenderConfig(
            camera={"width": conf.width, "height": conf.height, "fx": conf.focal_px,
                    "fy": conf.focal_px, "cx": conf.width / 2, "cy": conf.height / 2}
        )  # fmt: skip
        dataset = {
            "speed": 1.0,
            "dynamic_range": info["dynamic_range"],
            "duration": 1.0,
            "seed": seed,
        }
        scene = build_scene(spec, dataset, render, None)
        renderer = Renderer(scene, supersample=1)

        def radiance_at(t: float) -> np.ndarray:
            return renderer.radiance(motion.pose(t))

        recipe_extra = {"generator": "scene3d", **info, "scene": spec, "motion": motion.to_dict()}
    if conf.cutoff_hz[1] > 0:
        cam.cutoff_hz = _loguniform(np.random.default_rng([seed, 1]), *conf.cutoff_hz)
    return run_sequence(conf, split, seed, rng, radiance_at, cam, n, recipe_extra)


def _planar_recipe(
    conf: TrainDataConfig, split: str, rng: np.random.Generator
) -> tuple[Any, EventCameraConfig, int, dict[str, Any]]:
    from evdense.training.planar import PlanarScene

    hdr = rng.random() < conf.hdr_fraction
    dyn = _loguniform(rng, 10.0, conf.dynamic_range_max) if hdr else 1.0
    pictures = TRAIN_PICTURES + find_pictures(tuple(conf.picture_dirs))
    planar = PlanarConfig(texture_weights=dict(conf.planar_textures), pictures=pictures)
    scene = PlanarScene(rng, conf.width, conf.height, 0.5, dynamic_range=dyn, conf=planar)
    cam = _event_camera(conf, split, rng)
    n, epp = _window_size(conf, split, rng)
    info = {"generator": "planar", "kind": "hdr" if hdr else "smooth", "dynamic_range": dyn,
            "events_per_pixel": epp, "events_per_window": n,
            "layers": len(scene.layers)}  # fmt: skip
    return scene.radiance, cam, n, info


def run_sequence(
    conf: TrainDataConfig,
    split: str,
    seed: int,
    rng: np.random.Generator,
    radiance_at: Any,
    cam: EventCameraConfig,
    n: int,
    recipe_extra: dict[str, Any],
) -> Sequence | None:
    """Simulate the event camera ``cam`` over ``radiance_at`` until ``conf.windows_per_sequence``
    windows of ``n`` events are complete; their voxel grids and targets (None when the motion
    gives too few events within ``conf.max_duration_s`` seconds or ``conf.max_renders`` renders)."""
    need = n * conf.windows_per_sequence
    parts: list[Events] = []
    count = renders = 0

    def sink(ev: Events) -> None:
        nonlocal count
        parts.append(ev)
        count += len(ev)
        if count >= need:
            raise _Enough

    def counted(t: float) -> np.ndarray:
        nonlocal renders
        renders += 1
        if renders > conf.max_renders:
            raise _TooSlow
        return radiance_at(t)

    try:
        simulate_event_stream(counted, 0.0, conf.max_duration_s, cam, rng, sink)
    except (_Enough, _TooSlow):
        pass
    if count < need:
        log.info("sequence %d (%s): only %d of %d events, skipped", seed, split, count, need)
        return None
    ev = Events.concatenate(parts)[:need]
    idx = np.arange(0, need + 1, n, dtype=np.int64)
    nw = conf.windows_per_sequence
    h, w = conf.height, conf.width
    voxels = np.zeros((nw, conf.bins, h, w), np.float32)
    logr = np.zeros((nw, h, w), np.float32)
    t_end = np.zeros(nw, np.int64)
    for k in range(nw):
        a, b = idx[k], idx[k + 1]
        voxel_grid(ev.t[a:b], ev.x[a:b], ev.y[a:b], ev.p[a:b], conf.bins, h, w, out=voxels[k])
        t_end[k] = ev.t[b - 1]
        logr[k] = np.log(radiance_at(t_end[k] * 1e-6) + cam.log_eps)
    lo, hi = np.percentile(logr, conf.target_percentiles)
    hi = max(hi, lo + 1e-3)
    targets = power_targets(logr, (lo, hi), 0.0)
    recipe = {
        "split": split,
        "seed": seed,
        **recipe_extra,
        "event_camera": cam.to_dict(),
        "duration_s": float(t_end[-1]) * 1e-6,
    }
    return Sequence(voxels, targets, logr, t_end, idx, ev, (float(lo), float(hi)), recipe)


# ---------------------------------------------------------------------------------------------
# The cached set
# ---------------------------------------------------------------------------------------------


def _seed(base: int, split: str, i: int) -> int:
    return (base * 1_000_003 + SPLITS.index(split) * 100_003 + i) % (2**31)


def _simulate_job(job: tuple[TrainDataConfig, str, int]) -> Sequence | None:
    conf, split, seed = job
    import torch  # noqa: F401  (keep worker threads to one each)

    torch.set_num_threads(1)
    return simulate_sequence(conf, split, seed)


def generate_dataset(
    out_path: str | Path,
    conf: TrainDataConfig,
    splits: dict[str, int],
    seed: int = 0,
    store_events: tuple[str, ...] = ("heldout",),
    workers: int = 1,
) -> Path:
    """Simulate ``splits`` (split name -> number of sequences) and write them into one HDF5.

    Sequences are numbered per split (``/train/seq_00000``, ...). Attempt ``i`` of a split is
    seeded from ``seed``, the split and ``i``; attempts with too few events are skipped, and the
    first ``count`` good ones are kept in attempt order, so a set is reproducible whatever
    ``workers`` (processes) is. The events themselves are stored for the splits in
    ``store_events`` (the baselines need them). Written to ``<out>.partial`` and renamed when
    complete. Returns ``out_path``.
    """
    out_path = Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    tmp = out_path.with_name(out_path.name + ".partial")
    pool = None
    if workers > 1:
        import multiprocessing as mp

        pool = mp.get_context("spawn").Pool(workers)
    try:
        with h5py.File(tmp, "w") as f:
            f.attrs["format"] = TRAINSET_FORMAT
            f.attrs["version"] = TRAINSET_VERSION
            f.attrs["config"] = json.dumps(asdict(conf))
            f.attrs["seed"] = int(seed)
            f.attrs["splits"] = json.dumps(splits)
            for split, count in splits.items():
                g = f.create_group(split)
                if count == 0:  # an empty split: simulate nothing
                    continue
                max_attempts = 3 * count + 10
                jobs = ((conf, split, _seed(seed, split, i)) for i in range(max_attempts))
                results = pool.imap(_simulate_job, jobs) if pool else map(_simulate_job, jobs)
                attempts = [0]  # progress counts kept sequences; rejected attempts reported apart
                kept = _kept(results, attempts)
                made = 0
                for seq in progress(kept, total=count, desc=f"simulate {split}"):
                    _write_sequence(g.create_group(f"seq_{made:05d}"), seq, split in store_events)
                    made += 1
                    if made == count:
                        break
                if attempts[0] > made:
                    log.info("%s: %d of %d attempts had too few events", split,
                             attempts[0] - made, attempts[0])  # fmt: skip
                if made < count:
                    raise ValueError(
                        f"{out_path}: only {made} of {count} {split} sequences had enough events "
                        "(check contrast_range and max_duration_s)"
                    )
                if pool:  # drop the look-ahead jobs of this split
                    pool.terminate()
                    pool = mp.get_context("spawn").Pool(workers)
    finally:
        if pool:
            pool.terminate()
    os.replace(tmp, out_path)
    log.info("wrote %s (%s)", out_path, ", ".join(f"{k}: {v}" for k, v in splits.items()))
    return out_path


def _kept(results: Iterable[Sequence | None], attempts: list[int]) -> Iterator[Sequence]:
    """The sequences of ``results`` that had enough events; ``attempts[0]`` counts all of them."""
    for seq in results:
        attempts[0] += 1
        if seq is not None:
            yield seq


def _write_sequence(g: h5py.Group, seq: Sequence, store_events: bool) -> None:
    opts = {"compression": "gzip", "compression_opts": 1, "shuffle": True}
    nw = len(seq.targets)
    g.create_dataset(
        "voxels", data=seq.voxels.astype(np.float16), chunks=(1, *seq.voxels.shape[1:]), **opts
    )
    g.create_dataset(
        "targets", data=seq.targets.astype(np.float16), chunks=(1, *seq.targets.shape[1:]), **opts
    )
    g.create_dataset("log_radiance", data=seq.log_radiance, chunks=(1, *seq.targets.shape[1:]), **opts)  # fmt: skip
    g.create_dataset("t_end_us", data=seq.t_end_us)
    g["log_radiance_range"] = np.array(seq.log_range)
    g.attrs["recipe"] = json.dumps(seq.recipe)
    g.attrs["num_windows"] = nw
    if store_events:
        e = g.create_group("events")
        for name in ("t", "x", "y", "p"):
            e.create_dataset(name, data=getattr(seq.events, name), **opts)
        g["window_index"] = seq.window_index


def read_config(path: str | Path) -> TrainDataConfig:
    """The :class:`TrainDataConfig` a cached set was made with."""
    with h5py.File(path, "r") as f:
        _check_format(f, path)
        d = json.loads(f.attrs["config"])
    return TrainDataConfig(
        **{k: v for k, v in d.items() if k in {x.name for x in fields(TrainDataConfig)}}
    )


def read_seed(path: str | Path) -> int:
    """The seed a cached set was simulated with."""
    with h5py.File(path, "r") as f:
        _check_format(f, path)
        return int(f.attrs["seed"])


def read_splits(path: str | Path) -> dict[str, int]:
    """Split name -> number of sequences a cached set was made with."""
    with h5py.File(path, "r") as f:
        _check_format(f, path)
        return {k: int(v) for k, v in json.loads(f.attrs["splits"]).items()}


def _check_format(f: h5py.File, path: str | Path) -> None:
    if f.attrs.get("format") != TRAINSET_FORMAT:
        raise ValueError(f"{path}: not an evdense training set (format {f.attrs.get('format')!r})")


def power_targets(
    log_radiance: np.ndarray, log_range: tuple[float, float], power: float
) -> np.ndarray:
    """Targets in [0, 1] from log radiance in another tone: ``R ** power`` mapped to [0, 1] by the
    same robust range ``(q_lo, q_hi)`` as the stored log targets, i.e.
    ``clip((R**p - R_lo**p) / (R_hi**p - R_lo**p), 0, 1)`` with ``R_lo = exp(q_lo)``.

    ``power`` 1 is linear radiance (what FireNet was trained to output), 1/2.2 roughly
    display-encoded; as ``power`` tends to 0 it tends to the log targets, which ``power`` 0 returns
    exactly (it is the one definition of them: :func:`run_sequence` makes the stored targets with
    it). The percentiles stay those of the log range (a monotonic map keeps them), so a
    sequence's brightest 0.5 % still saturates and its darkest 0.5 % still clips at 0.
    """
    lo, hi = np.float64(log_range[0]), np.float64(log_range[1])
    logr = np.asarray(log_radiance)
    if logr.dtype == np.float16:  # as stored targets are; exp() needs more range
        logr = logr.astype(np.float32)
    if power == 0.0:
        t = (logr - lo) / max(hi - lo, 1e-12)
    else:  # relative to hi, so that exp() never overflows
        floor = np.exp(power * (lo - hi))
        t = (np.exp(power * (logr - hi)) - floor) / max(1.0 - floor, 1e-12)
    return np.clip(t, 0.0, 1.0).astype(np.float32)


def load_split(
    path: str | Path, split: str, target_power: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """All voxels ``(S, W, B, H, Wd)`` float16 and targets ``(S, W, H, Wd)`` float16 of one split.

    ``target_power``: None returns the stored (log) targets; a number derives them from the stored
    log radiance with :func:`power_targets` (0 gives the stored targets again, to float16
    rounding). Raises ``ValueError`` when the file is not a training set or lacks the split.
    """
    with h5py.File(path, "r") as f:
        _check_format(f, path)
        if split not in f:
            raise ValueError(f"{path}: no split {split!r} (has {', '.join(f)})")
        g = f[split]
        names = sorted(g)
        if not names:
            raise ValueError(f"{path}: split {split!r} has no sequences")
        vox = np.stack([g[n]["voxels"][()] for n in names])
        if target_power is None:
            tgt = np.stack([g[n]["targets"][()] for n in names])
        else:
            tgt = np.stack([
                power_targets(g[n]["log_radiance"][()], g[n]["log_radiance_range"][()],
                              target_power).astype(np.float16)
                for n in names
            ])  # fmt: skip
    return vox, tgt
