"""ESIM-style event camera: threshold crossings of per-pixel log intensity between renders.

The simulator keeps, for every pixel, a reference log intensity and the time of its last event.
Between two consecutive renders the log intensity of each pixel is taken as linear in time, so
every crossing of ``reference +- k * C`` gives one event with its own interpolated timestamp, and
the reference moves by ``C`` per crossing. The render step is chosen adaptively so that a high
percentile of the per-pixel change between renders stays a small fraction of ``C``; a finer step
then changes the events little (see ``benchmarks/bench_simulator.py``).

Refractory period: a crossing that comes sooner than ``refractory_us`` after the pixel's previous
*emitted* event is suppressed, but the reference still advances by ``C``. The pixel therefore keeps
tracking the log intensity (as in ESIM) instead of lagging behind it and releasing a burst of
stale events when the refractory period ends.

Photoreceptor bandwidth (``cutoff_hz`` > 0): a real pixel does not follow its log intensity
instantly. Its front end is close to a first-order low-pass whose cut-off frequency grows with the
photocurrent, so dim pixels lag and smear moving edges over time (the model v2e uses). Here every
pixel's log intensity passes through ``tau dy/dt = L - y`` with ``tau = 1 / (2 pi f)`` and
``f = cutoff_hz * clip(radiance / reference, cutoff_floor, 1)``, ``reference`` being the 99th
percentile of the first render's radiance (the renderers' radiance unit is arbitrary). Between two
renders L is linear in time, for which the filter has an exact solution at each render; the events
are then the threshold crossings of the filtered ``y`` instead of ``L``, their times interpolated
linearly between renders as for ``L``. At 0 (the default) nothing changes.

Noise: background-activity events (a Poisson process per pixel) and hot pixels (a fixed random
set of pixels firing at a high Poisson rate), both with random polarity. Noise events neither move
the reference nor start a refractory period.

All work is vectorised over pixels and events; the only Python loops run over render steps and
over "k-th crossing within one step" (needed for the refractory period, usually 1 to 3 passes).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from evdense.config import section_from_dict
from evdense.events.container import Events, EventWriter
from evdense.log import get_logger

log = get_logger("sim.esim")

RadianceFn = Callable[[float], np.ndarray]
"""A renderer as a plain callable: time (seconds) -> linear radiance image ``(H, W)``, > 0."""


@dataclass
class EventCameraConfig:
    """Settings of the simulated event camera (the ``simulator.event_camera`` config section)."""

    contrast_pos: float = 0.25
    """Nominal ON contrast threshold, in log-intensity units."""
    contrast_neg: float = 0.25
    """Nominal OFF contrast threshold, in log-intensity units."""
    contrast_sigma: float = 0.03
    """Standard deviation of the per-pixel threshold mismatch (Gaussian), log-intensity units."""
    contrast_min: float = 0.05
    """Per-pixel thresholds are clipped below at this value, log-intensity units."""
    log_eps: float = 1e-3
    """Offset in L = log(radiance + log_eps), radiance units; limits noise in near-black regions."""
    cutoff_hz: float = 0.0
    """Photoreceptor cut-off frequency at full brightness (Hz): a first-order low-pass on log
    intensity whose cut-off scales with the pixel's radiance (see the module docstring).
    0 = unlimited bandwidth, no filter."""
    cutoff_floor: float = 0.1
    """Lowest cut-off as a fraction of ``cutoff_hz`` (reached at and below this fraction of the
    reference radiance); only used when ``cutoff_hz`` > 0."""
    refractory_us: float = 100.0
    """Refractory period after an emitted event, microseconds (0 = none)."""
    noise_rate_hz: float = 0.1
    """Background-activity noise events per pixel per second (Hz)."""
    hot_pixel_fraction: float = 1e-4
    """Fraction of pixels that are hot."""
    hot_pixel_rate_hz: float = 20.0
    """Event rate of each hot pixel (Hz)."""
    step_tolerance: float = 0.8
    """Adaptive render step: the chosen percentile of |dL| between renders stays below this fraction of the nominal threshold."""
    step_percentile: float = 98.0
    """Percentile of |dL| over pixels that the adaptive step controls."""
    min_step_us: float = 20.0
    """Smallest render step, microseconds."""
    max_step_us: float = 5000.0
    """Largest render step, microseconds."""
    step_subdivisions: int = 1
    """Split every adaptive step into this many equal renders (2 halves the step; used by the convergence check)."""
    chunk_events: int = 1 << 20
    """Events buffered before they are written to the file (bounds memory)."""

    @classmethod
    def from_dict(cls, d: dict[str, Any] | None) -> EventCameraConfig:
        """Build from a config section; missing (or null) keys take the defaults, unknown keys
        raise ``ValueError``."""
        return section_from_dict(cls, d, "simulator.event_camera", drop_none=True)

    def check(self) -> None:
        """Raise ``ValueError`` naming the key when a value is out of range."""
        pos = {
            "contrast_pos": self.contrast_pos,
            "contrast_neg": self.contrast_neg,
            "contrast_min": self.contrast_min,
            "log_eps": self.log_eps,
            "step_tolerance": self.step_tolerance,
            "min_step_us": self.min_step_us,
            "max_step_us": self.max_step_us,
        }
        for k, v in pos.items():
            if not v > 0:
                raise ValueError(f"simulator.event_camera.{k} must be > 0, got {v}")
        nonneg = {
            "contrast_sigma": self.contrast_sigma,
            "refractory_us": self.refractory_us,
            "cutoff_hz": self.cutoff_hz,
            "noise_rate_hz": self.noise_rate_hz,
            "hot_pixel_fraction": self.hot_pixel_fraction,
            "hot_pixel_rate_hz": self.hot_pixel_rate_hz,
        }
        for k, v in nonneg.items():
            if v < 0:
                raise ValueError(f"simulator.event_camera.{k} must be >= 0, got {v}")
        if self.hot_pixel_fraction > 1:
            raise ValueError(
                f"simulator.event_camera.hot_pixel_fraction must be <= 1, got {self.hot_pixel_fraction}"
            )
        if not 0 < self.step_percentile <= 100:
            raise ValueError(
                f"simulator.event_camera.step_percentile must be in (0, 100], got {self.step_percentile}"
            )
        if not 0 < self.cutoff_floor <= 1:
            raise ValueError(
                f"simulator.event_camera.cutoff_floor must be in (0, 1], got {self.cutoff_floor}"
            )
        if self.min_step_us > self.max_step_us:
            raise ValueError("simulator.event_camera.min_step_us must not exceed max_step_us")
        if self.step_subdivisions < 1 or self.chunk_events < 1:
            raise ValueError(
                "simulator.event_camera.step_subdivisions and chunk_events must be >= 1"
            )

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def log_intensity(radiance: np.ndarray, eps: float) -> np.ndarray:
    """``log(radiance + eps)`` as float64, ``(H, W)``; raises ``ValueError`` on negative or non-finite radiance."""
    r = np.asarray(radiance, dtype=np.float64)
    if r.ndim != 2:
        raise ValueError(f"radiance image must be (H, W), got shape {r.shape}")
    if not np.all(np.isfinite(r)) or r.min() < 0:
        raise ValueError("radiance image must be finite and >= 0")
    return np.log(r + eps)


class EventSimulator:
    """Per-pixel state of an event camera of ``(height, width)`` pixels, advanced render by render.

    Call :meth:`reset` with the first log-intensity image, then :meth:`step` with each following one;
    each call returns the events in the interval ``(t_prev, t]`` sorted by time.
    """

    def __init__(
        self, height: int, width: int, config: EventCameraConfig, rng: np.random.Generator
    ) -> None:
        self.height, self.width = int(height), int(width)
        self.config = config
        self.rng = rng
        n = self.height * self.width
        c = config
        # Per-pixel threshold mismatch, drawn once per sensor.
        self.c_pos = np.maximum(
            c.contrast_pos + c.contrast_sigma * rng.standard_normal(n), c.contrast_min
        )
        self.c_neg = np.maximum(
            c.contrast_neg + c.contrast_sigma * rng.standard_normal(n), c.contrast_min
        )
        n_hot = int(round(c.hot_pixel_fraction * n))
        self.hot_pixels = (
            np.sort(rng.choice(n, size=n_hot, replace=False)) if n_hot else np.zeros(0, np.int64)
        )
        self._ref = np.zeros(n)
        self._L = np.zeros(n)
        self._t = 0.0
        self._last_us = np.full(n, np.iinfo(np.int64).min // 2, dtype=np.int64)
        self.num_suppressed = 0

    @property
    def reference(self) -> np.ndarray:
        """Current reference log intensity, ``(H, W)``."""
        return self._ref.reshape(self.height, self.width)

    def reset(self, log_image: np.ndarray, t: float) -> None:
        """Start at time ``t`` (seconds) with reference = ``log_image`` ``(H, W)``."""
        L = self._check(log_image)
        self._ref = L.copy()
        self._L = L.copy()
        self._t = float(t)

    def _check(self, log_image: np.ndarray) -> np.ndarray:
        L = np.asarray(log_image, dtype=np.float64)
        if L.shape != (self.height, self.width):
            raise ValueError(f"log image has shape {L.shape}, expected {(self.height, self.width)}")
        return L.ravel()

    def step(self, log_image: np.ndarray, t: float) -> Events:
        """Advance to time ``t`` (seconds, > previous) with log intensity ``(H, W)``; return the
        threshold-crossing events in ``(t_prev, t]``, sorted by time (no noise)."""
        L1 = self._check(log_image)
        t0, t1 = self._t, float(t)
        if not t1 > t0:
            raise ValueError(f"time must increase: {t1} after {t0}")
        L0, ref = self._L, self._ref
        d_up = L1 - ref
        n_pos = np.floor(np.maximum(d_up, 0.0) / self.c_pos).astype(np.int64)
        n_neg = np.floor(np.maximum(-d_up, 0.0) / self.c_neg).astype(np.int64)
        n = n_pos + n_neg  # at most one of the two is non-zero for a pixel
        pix = np.flatnonzero(n)
        if len(pix) == 0:
            self._L, self._t = L1, t1
            return Events.empty()
        counts = n[pix]
        sign = np.where(n_pos[pix] > 0, 1, -1).astype(np.int8)
        step_c = np.where(sign > 0, self.c_pos[pix], -self.c_neg[pix])
        ref_old = ref[pix]
        # Move the reference by C per crossing, whether or not the event is emitted.
        ref[pix] = ref_old + counts * step_c

        # One row per crossing: pixel, polarity, crossing number k = 1..count.
        rep = np.repeat(np.arange(len(pix)), counts)
        first = np.cumsum(counts) - counts
        k = np.arange(len(rep)) - first[rep] + 1
        level = ref_old[rep] + k * step_c[rep]
        p = pix[rep]
        dL = L1[p] - L0[p]
        # dL cannot be 0 at a crossing: the reference band (ref - C-, ref + C+) always contains L0.
        frac = np.clip((level - L0[p]) / dL, 0.0, 1.0)
        t_us = np.rint((t0 + frac * (t1 - t0)) * 1e6).astype(np.int64)
        pol = sign[rep]

        keep = self._refractory(p, k, t_us, int(counts.max()))
        self.num_suppressed += int(len(keep) - keep.sum())
        self._L, self._t = L1, t1
        ev_t, ev_p, ev_pol = t_us[keep], p[keep], pol[keep]
        order = np.argsort(ev_t, kind="stable")
        ev_p = ev_p[order]
        return Events(ev_t[order], ev_p % self.width, ev_p // self.width, ev_pol[order])

    def _refractory(self, p: np.ndarray, k: np.ndarray, t_us: np.ndarray, k_max: int) -> np.ndarray:
        """Mask of crossings that are emitted; updates the per-pixel last-event time."""
        refr = int(round(self.config.refractory_us))
        if refr <= 0:
            np.maximum.at(self._last_us, p, t_us)
            return np.ones(len(p), dtype=bool)
        keep = np.zeros(len(p), dtype=bool)
        # Crossings of one pixel are ordered by k; within one k every pixel appears at most once.
        for kk in range(1, k_max + 1):
            rows = np.flatnonzero(k == kk)
            ok = t_us[rows] - self._last_us[p[rows]] >= refr
            rows = rows[ok]
            keep[rows] = True
            self._last_us[p[rows]] = t_us[rows]
        return keep

    def noise(self, t0: float, t1: float) -> Events:
        """Background-activity and hot-pixel events in ``(t0, t1]`` (seconds), sorted by time."""
        c, rng = self.config, self.rng
        dt = t1 - t0
        n_pix = self.height * self.width
        parts = []
        if c.noise_rate_hz > 0:
            m = rng.poisson(c.noise_rate_hz * n_pix * dt)
            parts.append(rng.integers(0, n_pix, size=m))
        if c.hot_pixel_rate_hz > 0 and len(self.hot_pixels):
            counts = rng.poisson(c.hot_pixel_rate_hz * dt, size=len(self.hot_pixels))
            parts.append(np.repeat(self.hot_pixels, counts))
        if not parts:
            return Events.empty()
        pix = np.concatenate(parts)
        if len(pix) == 0:
            return Events.empty()
        t_us = np.rint(rng.uniform(t0, t1, size=len(pix)) * 1e6).astype(np.int64)
        t_us = np.clip(t_us, int(np.floor(t0 * 1e6)) + 1, int(np.rint(t1 * 1e6)))
        pol = rng.choice(np.array([-1, 1], dtype=np.int8), size=len(pix))
        order = np.argsort(t_us, kind="stable")
        pix = pix[order]
        return Events(t_us[order], pix % self.width, pix // self.width, pol[order])


class PhotoreceptorFilter:
    """The pixels' bandwidth: a first-order low-pass on log intensity, cut-off rising with radiance.

    Start it with the first log image; :meth:`advance` takes the next log image ``dt`` seconds
    later and returns the filtered log image, exact for an input linear in time between the two.
    """

    def __init__(self, log_image: np.ndarray, config: EventCameraConfig) -> None:
        self.config = config
        self._L = np.asarray(log_image, dtype=np.float64).copy()
        self._y = self._L.copy()
        radiance = np.exp(self._L) - config.log_eps
        self.reference = max(float(np.percentile(radiance, 99.0)), 1e-12)

    def advance(self, log_image: np.ndarray, dt: float) -> np.ndarray:
        """The filtered log image ``dt`` seconds after the last one; each pixel's cut-off is taken
        at its radiance in ``log_image`` and held over the step."""
        c = self.config
        L1 = np.asarray(log_image, dtype=np.float64)
        rel = np.clip((np.exp(L1) - c.log_eps) / self.reference, c.cutoff_floor, 1.0)
        tau = 1.0 / (2.0 * np.pi * c.cutoff_hz * rel)
        slope_tau = (L1 - self._L) / dt * tau
        # y(t) for tau y' = L(t) - y with L linear over the step: L1 - s tau + (y0 - L0 + s tau) e^(-dt/tau)
        self._y = L1 - slope_tau + (self._y - self._L + slope_tau) * np.exp(-dt / tau)
        self._L = L1
        return self._y.copy()


def merge_sorted(a: Events, b: Events) -> Events:
    """Merge two time-sorted batches into one time-sorted batch."""
    if len(a) == 0:
        return b
    if len(b) == 0:
        return a
    ev = Events.concatenate([a, b])
    return ev[np.argsort(ev.t, kind="stable")]


@dataclass
class EventStreamStats:
    """What one simulation did: renders, accepted steps, events (signal and noise), suppressed crossings."""

    renders: int = 0
    steps: int = 0
    rejected_steps: int = 0
    signal_events: int = 0
    noise_events: int = 0
    suppressed: int = 0
    min_step_s: float = float("inf")
    max_step_s: float = 0.0

    @property
    def num_events(self) -> int:
        return self.signal_events + self.noise_events


class _Buffer:
    """Collects event batches and hands them to ``sink`` in chunks of about ``chunk`` events."""

    def __init__(self, sink: Callable[[Events], None], chunk: int) -> None:
        self.sink, self.chunk, self.parts, self.n = sink, chunk, [], 0

    def add(self, ev: Events) -> None:
        if len(ev):
            self.parts.append(ev)
            self.n += len(ev)
            if self.n >= self.chunk:
                self.flush()

    def flush(self) -> None:
        if self.parts:
            self.sink(Events.concatenate(self.parts))
            self.parts, self.n = [], 0


def simulate_event_stream(
    radiance_at: RadianceFn,
    t_start: float,
    t_end: float,
    config: EventCameraConfig,
    rng: np.random.Generator,
    sink: Callable[[Events], None],
    step_log: list[float] | None = None,
) -> EventStreamStats:
    """Simulate the event camera from ``t_start`` to ``t_end`` (seconds) over a renderer.

    ``radiance_at(t)`` returns the linear radiance ``(H, W)`` at time ``t`` (seconds). Events are
    passed to ``sink`` in time order, in batches of about ``config.chunk_events``. When
    ``step_log`` is given, the accepted render times are appended to it.
    """
    c = config
    tol = c.step_tolerance * min(c.contrast_pos, c.contrast_neg)
    target = 0.7 * tol  # aim below the tolerance so that few steps are rejected
    min_step, max_step = c.min_step_us * 1e-6, c.max_step_us * 1e-6
    stats = EventStreamStats()

    L = log_intensity(radiance_at(t_start), c.log_eps)
    stats.renders += 1
    sim = EventSimulator(L.shape[0], L.shape[1], c, rng)
    sim.reset(L, t_start)
    lowpass = PhotoreceptorFilter(L, c) if c.cutoff_hz > 0 else None

    def sensed(L_next: np.ndarray, step: float) -> np.ndarray:
        """What the pixels compare with their reference: ``L_next`` itself or its low-passed value."""
        return L_next if lowpass is None else lowpass.advance(L_next, step)

    buf = _Buffer(sink, c.chunk_events)
    t = float(t_start)
    dt = min_step * 4
    eps_t = 1e-9
    while t < t_end - eps_t:
        dt = min(dt, t_end - t)
        while True:
            L_new = log_intensity(radiance_at(t + dt), c.log_eps)
            stats.renders += 1
            change = float(np.percentile(np.abs(L_new - L), c.step_percentile))
            if change <= tol or dt <= min_step * (1 + 1e-9) or t + dt >= t_end and dt < min_step:
                break
            stats.rejected_steps += 1
            dt = max(dt * min(0.5, target / change), min_step)
        t_new = t + dt
        events = []
        t_prev = t
        for j in range(1, c.step_subdivisions):
            tj = t + dt * j / c.step_subdivisions
            events.append(
                sim.step(sensed(log_intensity(radiance_at(tj), c.log_eps), tj - t_prev), tj)
            )
            stats.renders += 1
            t_prev = tj
        events.append(sim.step(sensed(L_new, t_new - t_prev), t_new))
        sig = Events.concatenate(events)  # sub-steps are consecutive, so already sorted
        noise = sim.noise(t, t_new)
        stats.signal_events += len(sig)
        stats.noise_events += len(noise)
        buf.add(merge_sorted(sig, noise))
        if step_log is not None:
            step_log.append(t_new)
        stats.steps += 1
        stats.min_step_s = min(stats.min_step_s, dt)
        stats.max_step_s = max(stats.max_step_s, dt)
        t, L = t_new, L_new
        grow = 2.0 if change <= 0 else float(np.clip(target / change, 0.5, 2.0))
        dt = float(np.clip(dt * grow, min_step, max_step))
    buf.flush()
    stats.suppressed = sim.num_suppressed
    return stats


def write_event_stream(
    radiance_at: RadianceFn,
    t_start: float,
    t_end: float,
    config: EventCameraConfig,
    rng: np.random.Generator,
    out_path: str | Path,
    provenance: dict[str, Any] | None = None,
    attrs: dict[str, Any] | None = None,
) -> EventStreamStats:
    """Simulate ``[t_start, t_end]`` seconds and write the canonical event file ``out_path``.

    The sensor size comes from the first render. The file holds the settings as the attribute
    ``event_camera`` and the run statistics as ``simulation_stats``; it appears under its final
    name only when complete.
    """
    first = np.asarray(radiance_at(t_start))
    if first.ndim != 2:
        raise ValueError(f"radiance image must be (H, W), got shape {first.shape}")
    height, width = first.shape
    all_attrs = {"simulator": "evdense-esim", "event_camera": config.to_dict(), **(attrs or {})}
    with EventWriter(out_path, width, height, provenance=provenance, attrs=all_attrs) as writer:
        stats = simulate_event_stream(radiance_at, t_start, t_end, config, rng, writer.append)
        # EventWriter writes its attrs dict on close, so the statistics can still be added here.
        all_attrs["simulation_stats"] = asdict(stats)
    log.info(
        "wrote %d events (%d noise) from %d renders (%d steps, %.0f-%.0f us) to %s",
        stats.num_events,
        stats.noise_events,
        stats.renders,
        stats.steps,
        stats.min_step_s * 1e6,
        stats.max_step_s * 1e6,
        out_path,
    )
    return stats
