"""Smooth camera trajectories: a cubic spline through key poses, or a parametric orbit.

Specs (YAML-friendly dicts; positions and targets in metres, world z up)::

    {type: spline, key_poses: [{position: [x, y, z], look_at: [x, y, z]}, ...], times: [optional]}
    {type: orbit, center: [x, y, z], radius: 2.0, height: 1.5, start_deg: -40, end_deg: 40,
     look_at: [x, y, z], bob: 0.1}

Both the camera position and the point it looks at follow a spline (or the orbit), and the orientation
comes from looking at that point with world z up, so paths are smooth and never roll.
Time: ``pose(t)`` takes seconds of the recording, ``0 <= t <= duration``; the path itself lasts
``path_duration`` seconds at speed 1 and is travelled ``speed`` times faster.
"""

from __future__ import annotations

import numbers
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import CubicSpline

TRAJECTORY_TYPES = ("spline", "orbit")


def look_at_batch(eye: np.ndarray, target: np.ndarray, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Camera-to-world poses ``(N, 4, 4)`` of cameras at ``eye`` ``(N, 3)`` looking at ``target``
    ``(N, 3)`` (x right, y down, z forward; ``up`` is world up). Same convention as
    :func:`evdense.poses.look_at`."""
    eye = np.asarray(eye, np.float64)
    z = np.asarray(target, np.float64) - eye
    z /= np.linalg.norm(z, axis=-1, keepdims=True)
    x = np.cross(z, np.asarray(up, np.float64))
    x /= np.maximum(np.linalg.norm(x, axis=-1, keepdims=True), 1e-12)
    y = np.cross(z, x)
    T = np.zeros((len(eye), 4, 4))
    T[:, :3, 0], T[:, :3, 1], T[:, :3, 2], T[:, :3, 3] = x, y, z, eye
    T[:, 3, 3] = 1.0
    return T


def _vec3(v, key: str) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64) if isinstance(v, list | tuple | np.ndarray) else None
    if a is None or a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{key}: expected 3 numbers [x, y, z], got {v!r}")
    return a


@dataclass
class Trajectory:
    """A smooth camera path; ``pose(t)`` gives camera-to-world ``T_wc`` at recording time ``t`` (s).

    ``position_fn`` and ``target_fn`` map path time (seconds at speed 1, ``0..path_duration``) to
    ``(N, 3)`` world points (metres).
    """

    position_fn: Callable[[np.ndarray], np.ndarray]
    target_fn: Callable[[np.ndarray], np.ndarray]
    path_duration: float
    speed: float = 1.0
    spec: dict = field(default_factory=dict)

    @property
    def duration(self) -> float:
        """Seconds of the recording (``path_duration / speed``)."""
        return self.path_duration / self.speed

    def pose(self, t: float | np.ndarray) -> np.ndarray:
        """Camera-to-world pose at recording time ``t`` (seconds from 0): ``(4, 4)`` for a scalar,
        ``(N, 4, 4)`` for an array. Times outside ``[0, duration]`` are clamped to the ends."""
        scalar = np.ndim(t) == 0
        tt = np.atleast_1d(np.asarray(t, dtype=np.float64))
        s = np.clip(tt * self.speed, 0.0, self.path_duration)
        T = look_at_batch(self.position_fn(s), self.target_fn(s))
        return T[0] if scalar else T

    def sample(self, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
        """Poses on a regular grid at ``rate_hz`` including both ends: times ``(N,)`` s, ``(N, 4, 4)``."""
        n = max(2, int(np.ceil(self.duration * rate_hz)) + 1)
        t = np.linspace(0.0, self.duration, n)
        return t, self.pose(t)


def make_trajectory(
    spec: dict, duration: float, speed: float = 1.0, key: str = "trajectory"
) -> Trajectory:
    """Build a :class:`Trajectory` from a spec (see module docstring) lasting ``duration`` seconds at
    speed 1, travelled ``speed`` times faster. Raises ``ValueError`` naming the offending key."""
    if not isinstance(spec, dict):
        raise ValueError(f"{key}: expected a mapping, got {spec!r}")
    if not (isinstance(duration, numbers.Real) and np.isfinite(duration) and duration > 0):
        raise ValueError(f"duration: must be a number > 0 (seconds), got {duration!r}")
    if not (isinstance(speed, numbers.Real) and np.isfinite(speed) and speed > 0):
        raise ValueError(f"speed: must be a number > 0, got {speed!r}")
    kind = spec.get("type", "spline")
    if kind == "spline":
        pos_fn, tgt_fn = _spline(spec, float(duration), key)
    elif kind == "orbit":
        pos_fn, tgt_fn = _orbit(spec, float(duration), key)
    else:
        raise ValueError(
            f"{key}.type: unknown trajectory type {kind!r} (known: {', '.join(TRAJECTORY_TYPES)})"
        )
    return Trajectory(pos_fn, tgt_fn, float(duration), float(speed), spec)


def _spline(spec: dict, duration: float, key: str):
    allowed = {"type", "key_poses", "times"}
    for k in spec:
        if k not in allowed:
            raise ValueError(
                f"{key}.{k}: unknown option for a spline trajectory (known: {sorted(allowed)})"
            )
    kp = spec.get("key_poses")
    if not isinstance(kp, list) or len(kp) < 2:
        n = len(kp) if isinstance(kp, list) else 0
        raise ValueError(f"{key}.key_poses: need at least 2 key poses, got {n}")
    pos, tgt = [], []
    for i, p in enumerate(kp):
        if not isinstance(p, dict) or set(p) != {"position", "look_at"}:
            raise ValueError(
                f"{key}.key_poses[{i}]: expected {{position: [x, y, z], look_at: [x, y, z]}}, got {p!r}"
            )
        pos.append(_vec3(p["position"], f"{key}.key_poses[{i}].position"))
        tgt.append(_vec3(p["look_at"], f"{key}.key_poses[{i}].look_at"))
        if np.linalg.norm(tgt[-1] - pos[-1]) < 1e-6:
            raise ValueError(f"{key}.key_poses[{i}]: look_at equals position")
    pos_a, tgt_a = np.stack(pos), np.stack(tgt)
    if "times" in spec:
        times = np.asarray(spec["times"], dtype=np.float64)
        if times.shape != (len(kp),) or np.any(np.diff(times) <= 0):
            raise ValueError(
                f"{key}.times: need {len(kp)} strictly increasing numbers, got {spec['times']!r}"
            )
    else:
        # chord-length parametrisation: roughly constant speed along the path
        step = np.linalg.norm(np.diff(pos_a, axis=0), axis=1) + 0.25 * np.linalg.norm(
            np.diff(tgt_a, axis=0), axis=1
        )
        if np.any(step < 1e-9):
            raise ValueError(f"{key}.key_poses: two consecutive key poses are identical")
        times = np.concatenate([[0.0], np.cumsum(step)])
    times = (times - times[0]) / (times[-1] - times[0]) * duration
    ps = CubicSpline(times, pos_a, bc_type="natural")
    ts = CubicSpline(times, tgt_a, bc_type="natural")
    return ps, ts


def _orbit(spec: dict, duration: float, key: str):
    defaults = {"radius": 2.0, "height": 1.5, "start_deg": -45.0, "end_deg": 45.0, "bob": 0.0}
    allowed = set(defaults) | {"type", "center", "look_at"}
    for k in spec:
        if k not in allowed:
            raise ValueError(
                f"{key}.{k}: unknown option for an orbit trajectory (known: {sorted(allowed)})"
            )
    o = {**defaults, **spec}
    centre = _vec3(o.get("center"), f"{key}.center")
    target = _vec3(o.get("look_at", list(centre)), f"{key}.look_at")
    if not o["radius"] > 0:
        raise ValueError(f"{key}.radius: must be > 0, got {o['radius']}")
    a0, a1 = np.deg2rad(float(o["start_deg"])), np.deg2rad(float(o["end_deg"]))
    if a0 == a1:
        raise ValueError(f"{key}.end_deg: must differ from start_deg")
    r, h, bob = float(o["radius"]), float(o["height"]), float(o["bob"])

    def position(s: np.ndarray) -> np.ndarray:
        u = s / duration
        a = a0 + (a1 - a0) * u
        z = centre[2] + h + bob * np.sin(2 * np.pi * u)
        return np.stack([centre[0] + r * np.cos(a), centre[1] + r * np.sin(a), z], axis=-1)

    def look(s: np.ndarray) -> np.ndarray:
        return np.broadcast_to(target, (len(s), 3)).copy()

    return position, look
