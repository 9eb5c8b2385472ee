"""Conventional frame camera: exposure blur, auto-exposure, full-well saturation, noise, 8 bits.

Frame ``k`` is exposed from ``t_start + k / fps`` for ``exposure`` seconds; its timestamp is the
middle of the exposure. The radiance is integrated over the exposure as the mean of sub-renders at
the midpoints of equal sub-intervals (so fast motion blurs); their number is fixed, or refined
1, 3, 9, 27, ... (reusing earlier sub-renders) until the blurred image stops changing.

Photometry: electrons = radiance * scale, where ``scale`` (electrons per radiance unit) comes from
auto-exposure (a percentile of the frame mapped to ``target_level`` of the full well; metered
once, or per frame with exponential smoothing) or from ``sensitivity`` * exposure when
auto-exposure is off. Then Poisson shot noise, Gaussian read noise, clipping at the full well
(so an HDR scene saturates exactly where an 8-bit camera would), an optional gamma, and 8-bit
quantisation: 0 electrons -> 0, full well -> 255.
"""

from __future__ import annotations

import json
import math
import os
import shutil
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import imageio.v3 as iio
import numpy as np

from evdense.config import section_from_dict
from evdense.formats.frames import frame_name, write_timestamps
from evdense.log import get_logger, progress
from evdense.sim.esim import RadianceFn

log = get_logger("sim.conventional")

AUTO_EXPOSURE_MODES = ("off", "once", "per_frame")


@dataclass
class ConventionalCameraConfig:
    """Settings of the simulated frame camera (the ``simulator.conventional_camera`` config section)."""

    fps: float = 20.0
    """Frame rate (Hz)."""
    exposure_s: float = 0.01
    """Exposure time (seconds); must not exceed the frame period."""
    exposure_fraction: float | None = None
    """When set, the exposure is this fraction of the frame period and ``exposure_s`` is ignored."""
    subframes: int = 0
    """Sub-renders averaged per exposure; 0 = adaptive (1, 3, 9, 27, ... until the mean converges)."""
    subframe_tolerance: float = 0.02
    """Adaptive sub-renders: stop when the 99th percentile of the relative change of the mean is below this."""
    max_subframes: int = 27
    """Upper bound on adaptive sub-renders per exposure."""
    auto_exposure: str = "per_frame"
    """Auto-exposure mode: off (fixed sensitivity), once (metered on the first frame), per_frame (smoothed)."""
    metering_percentile: float = 50.0
    """Auto-exposure maps this percentile of the frame's radiance to ``target_level``."""
    target_level: float = 0.4
    """Auto-exposure target as a fraction of the full well (0.4 ~ 100 of 255 with gamma 1)."""
    ae_smoothing: float = 0.5
    """Per-frame auto-exposure: weight of the new metering in log scale (1 = no smoothing)."""
    sensitivity: float = 1.0e5
    """Electrons per radiance unit per second of exposure when auto-exposure is off."""
    full_well_e: float = 10000.0
    """Full-well capacity (electrons); it reads 255."""
    read_noise_e: float = 4.0
    """Read noise standard deviation (electrons); 0 = none."""
    shot_noise: bool = True
    """Poisson shot noise on the collected electrons."""
    gamma: float = 1.0
    """Output gamma: value = (electrons / full_well) ** (1 / gamma); 1 = linear like a DAVIS APS frame."""

    @classmethod
    def from_dict(cls, d: dict[str, Any] | None) -> ConventionalCameraConfig:
        """Build from a config section; missing (or null) keys take the defaults (a null
        ``exposure_fraction`` is its default: use ``exposure_s``), unknown keys raise ``ValueError``."""
        return section_from_dict(cls, d, "simulator.conventional_camera", drop_none=True)

    @property
    def exposure(self) -> float:
        """Exposure time in seconds."""
        if self.exposure_fraction is not None:
            return self.exposure_fraction / self.fps
        return self.exposure_s

    def check(self) -> None:
        """Raise ``ValueError`` naming the key when a value is out of range."""
        p = "simulator.conventional_camera."
        if not self.fps > 0:
            raise ValueError(f"{p}fps must be > 0, got {self.fps}")
        if self.exposure_fraction is not None and not 0 < self.exposure_fraction <= 1:
            raise ValueError(
                f"{p}exposure_fraction must be in (0, 1], got {self.exposure_fraction}"
            )
        if not 0 < self.exposure <= 1.0 / self.fps + 1e-12:
            raise ValueError(
                f"{p}exposure_s must be in (0, 1/fps = {1 / self.fps:.4g}] s, got {self.exposure}"
            )
        if self.subframes < 0 or self.max_subframes < 1:
            raise ValueError(f"{p}subframes must be >= 0 and max_subframes >= 1")
        if self.auto_exposure not in AUTO_EXPOSURE_MODES:
            raise ValueError(
                f"{p}auto_exposure must be one of {AUTO_EXPOSURE_MODES}, got {self.auto_exposure!r}"
            )
        if not 0 <= self.metering_percentile <= 100:
            raise ValueError(f"{p}metering_percentile must be in [0, 100]")
        for k in ("target_level", "ae_smoothing"):
            if not 0 < getattr(self, k) <= 1:
                raise ValueError(f"{p}{k} must be in (0, 1], got {getattr(self, k)}")
        for k in ("sensitivity", "full_well_e", "gamma", "subframe_tolerance"):
            if not getattr(self, k) > 0:
                raise ValueError(f"{p}{k} must be > 0, got {getattr(self, k)}")
        if self.read_noise_e < 0:
            raise ValueError(f"{p}read_noise_e must be >= 0")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def frame_times(
    duration: float, config: ConventionalCameraConfig, t_start: float = 0.0
) -> np.ndarray:
    """Exposure start times (seconds) of every frame whose exposure ends by ``t_start + duration``."""
    period, exp = 1.0 / config.fps, config.exposure
    n = int(math.floor((duration - exp) / period + 1e-9)) + 1 if duration >= exp - 1e-12 else 0
    return t_start + period * np.arange(n)


def subrender_times(t0: float, exposure: float, n: int) -> np.ndarray:
    """Midpoints of ``n`` equal sub-intervals of the exposure ``[t0, t0 + exposure]`` (seconds)."""
    return t0 + exposure * (np.arange(n) + 0.5) / n


def integrate_exposure(radiance_at: RadianceFn, t0: float, exposure: float, n: int) -> np.ndarray:
    """Mean radiance over ``[t0, t0 + exposure]`` from ``n`` sub-renders, ``(H, W)`` float64."""
    acc = None
    for t in subrender_times(t0, exposure, n):
        r = np.asarray(radiance_at(float(t)), dtype=np.float64)
        acc = r.copy() if acc is None else acc + r
    assert acc is not None
    return acc / n


def integrate_exposure_adaptive(
    radiance_at: RadianceFn, t0: float, exposure: float, tolerance: float, max_subframes: int
) -> tuple[np.ndarray, int]:
    """Mean radiance over the exposure with 1, 3, 9, ... sub-renders until it converges.

    Each refinement splits every sub-interval in three, so the previous sub-renders (the middle
    thirds' midpoints) are reused. It stops when the 99th percentile of the relative change of the
    mean is at most ``tolerance``, or when tripling again would exceed ``max_subframes``. Returns
    the finest mean ``(H, W)`` float64 (equal to the mean of its sub-renders at
    :func:`subrender_times`) and the number of sub-renders.
    """
    n = 1
    total = np.asarray(radiance_at(t0 + exposure / 2), dtype=np.float64).copy()
    mean = total
    while 3 * n <= max_subframes:
        times = subrender_times(t0, exposure, 3 * n)
        for j, t in enumerate(times):
            if j % 3 != 1:  # j % 3 == 1 are the previous level's midpoints
                total = total + np.asarray(radiance_at(float(t)), dtype=np.float64)
        n *= 3
        new = total / n
        floor = 0.01 * float(np.median(mean)) + 1e-12
        change = float(np.percentile(np.abs(new - mean) / (mean + floor), 99))
        mean = new
        if change <= tolerance:
            break
    return mean, n


def meter(radiance: np.ndarray, config: ConventionalCameraConfig) -> float:
    """Auto-exposure scale (electrons per radiance unit) mapping the metering percentile to the target."""
    level = float(np.percentile(radiance, config.metering_percentile))
    if not level > 0:
        level = float(np.max(radiance)) or 1.0
    return config.target_level * config.full_well_e / level


def expose(
    radiance: np.ndarray,
    scale: float,
    config: ConventionalCameraConfig,
    rng: np.random.Generator | None,
) -> np.ndarray:
    """8-bit image ``(H, W)`` uint8 from mean radiance ``(H, W)`` and ``scale`` electrons per radiance unit.

    With ``rng=None`` no noise is added (an exact, deterministic reading).
    """
    e = np.asarray(radiance, dtype=np.float64) * scale
    fw = config.full_well_e
    if rng is not None:
        if config.shot_noise:
            # Electrons beyond the full well are lost anyway; capping keeps Poisson in range for HDR.
            e = rng.poisson(np.minimum(e, 2 * fw)).astype(np.float64)
        if config.read_noise_e > 0:
            e = e + config.read_noise_e * rng.standard_normal(e.shape)
    v = np.clip(e / fw, 0.0, 1.0)
    if config.gamma != 1.0:
        v = v ** (1.0 / config.gamma)
    return np.rint(v * 255.0).astype(np.uint8)


@dataclass
class FrameRecord:
    """One written frame: index, timestamp (middle of exposure, s), sub-renders, scale (e-/radiance unit), saturated fraction."""

    index: int
    t: float
    subframes: int
    scale: float
    saturated: float


def simulate_frames(
    radiance_at: RadianceFn,
    duration: float,
    config: ConventionalCameraConfig,
    rng: np.random.Generator | None,
    out_dir: str | Path,
    t_start: float = 0.0,
    extra: dict[str, Any] | None = None,
) -> list[FrameRecord]:
    """Write the frame camera's output for ``[t_start, t_start + duration]`` seconds to ``out_dir``.

    ``out_dir/frames/000000.png ...``, ``out_dir/frames/timestamps.txt`` (``index t_seconds``, middle
    of exposure) and ``out_dir/settings.json``. Everything is written to ``<out_dir>.partial`` and
    renamed when complete, replacing an existing ``out_dir``. ``rng=None`` disables noise.
    """
    out_dir = Path(out_dir)
    tmp = out_dir.with_name(out_dir.name + ".partial")
    if tmp.exists():
        shutil.rmtree(tmp)
    (tmp / "frames").mkdir(parents=True)
    exp = config.exposure
    starts = frame_times(duration, config, t_start)
    if len(starts) == 0:
        raise ValueError(f"sequence of {duration} s is shorter than one exposure ({exp} s)")
    records: list[FrameRecord] = []
    log_scale: float | None = None
    renders = 0
    try:
        for i, t0 in progress(list(enumerate(starts)), desc="conventional frames", logger=log):
            if config.subframes > 0:
                n = config.subframes
                img = integrate_exposure(radiance_at, float(t0), exp, n)
            else:
                img, n = integrate_exposure_adaptive(
                    radiance_at, float(t0), exp, config.subframe_tolerance, config.max_subframes
                )
            renders += n
            if config.auto_exposure == "off":
                scale = config.sensitivity * exp
            elif log_scale is None or config.auto_exposure == "per_frame":
                new = math.log(meter(img, config))
                a = config.ae_smoothing if log_scale is not None else 1.0
                log_scale = new if log_scale is None else (1 - a) * log_scale + a * new
                scale = math.exp(log_scale)
            else:
                scale = math.exp(log_scale)
            frame = expose(img, scale, config, rng)
            iio.imwrite(tmp / "frames" / frame_name(i), frame)
            sat = float(np.mean(img * scale >= config.full_well_e))
            records.append(FrameRecord(i, float(t0 + exp / 2), n, scale, sat))
        write_timestamps(tmp / "frames", [r.index for r in records], [r.t for r in records])
        settings = {
            "camera": config.to_dict(),
            "exposure_s": exp,
            "num_frames": len(records),
            "renders": renders,
            "noise": rng is not None,
            "frames": [asdict(r) for r in records],
            **(extra or {}),
        }
        (tmp / "settings.json").write_text(json.dumps(settings, indent=1, default=str))
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if out_dir.exists():
        shutil.rmtree(out_dir)
    os.replace(tmp, out_dir)
    log.info("wrote %d frames (%d renders) to %s", len(records), renders, out_dir)
    return records
