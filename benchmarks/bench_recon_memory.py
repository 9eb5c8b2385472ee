"""Does a reconstruction network remember a plain surface after an edge has crossed it?

Usage: PYTHONPATH=src .venv/bin/python benchmarks/bench_recon_memory.py
           [--ours resources/weights/evfirenet.pt [more.pt ...]] [--anchors ../shared/anchors]
           [--contrast-sigma 0.03] [--events-per-pixel 0.1] [--threads 2]
           [--probes bar level fill] [--hold 3] [--level-ratio 5]

A probe built from exact geometry, not from a training generator: a 240 x 180 sensor looks at a
plain surface (the top 60 % of the view) above a strip of 1/f texture that scrolls sideways all
the time (the bottom 30 %), so windows of N events keep coming from the strip. In the first
second a bar 40 px wide and as tall as the surface crosses it once, left to right, and leaves;
for the next second the surface is plain again. Two cases: a dark bar (a fifth of the radiance)
over a light surface, and a light bar (five times the radiance) over a dark one. Every pixel of
the surface sees the bar arrive and leave, so an ideal integrator of the events (one that knows
each pixel's thresholds) gives a uniform surface back: the events where the bar arrived are undone
by those where it left. A network that forgets (a leaky, high-pass response) leaves a trail whose strength grows with the time since
the bar passed, the ghosts behind moving edges seen on real recordings. Summing each pixel's
events times the nominal threshold (the last row) is exact only without threshold mismatch: with
it, every pixel keeps its own residual, so that row shows how much a network must also smooth.

Events come from our ESIM core (:func:`evdense.sim.esim.simulate_event_stream`) with equal ON and
OFF thresholds of 0.2, no noise, and a per-pixel threshold spread of each ``--contrast-sigma``.
Each network starts from an empty state. Printed per network, the mean of the two cases: the
residual contrast on the surface once the bar has left (the 2nd-98th percentile span of the
surface over the frame's 1st-99th, so 0 for a uniform surface; the surface's edges and the strip
are left out), averaged over the windows of three intervals after the bar left. About 2 x 1.3 M
events, 2 x 100 windows after the crossing; 4.5 minutes for 7 networks on one thread.

The second probe (``--probes level``) asks the converse: does a network keep a level that events
set? A plain curtain slides in from the left over the first second and parks over the left half
of the surface, so the surface ends as two plain halves of different radiance (``--level-ratio``,
5 by default, the darker half on the lighter or the lighter on the darker) with a static
boundary, and no event falls on it for the next ``--hold`` seconds. An integrator keeps the step
between the halves; a network that lets an event-free region relax towards a prior level loses
it. Printed: the signed step between the halves' medians (the curtain's half minus the other,
the dark case negated), over the frame's 1st-99th percentile span, averaged over intervals after
the curtain parked, and what the GT frame gives in log and in linear radiance. A step that
shrinks with time is a leak.

The third (``--probes fill``) starts with the two halves in place, so no event says their levels,
and sways their boundary by 12 px; the step, taken 24 px or more from the boundary, is there only
if a network spreads the edge's level into the plain halves. (FireNet does neither this nor keep
the level above, yet holds the plain walls of ``bench_recon_stability.py``'s room best:
docs/training.md, "Levels, fill-in and the plain room".) All three probes run by default, about
three times the bar probe's time; ``--probes`` picks some.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from evdense.events.container import Events
from evdense.events.voxel import voxel_grid
from evdense.recon.checkpoints import load_checkpoint
from evdense.recon.inference import NetworkReconstructor
from evdense.sim.esim import EventCameraConfig, simulate_event_stream
from evdense.sim.textures import spectral_noise

ROOT = Path(__file__).resolve().parents[1]
W, H = 240, 180
SURFACE = slice(0, int(0.6 * H))
STRIP = slice(int(0.7 * H), H)
T_CROSS, T_END = 1.0, 2.0


CASES = {"dark bar": (0.5, 0.1), "light bar": (0.1, 0.5)}
"""Radiance of the surface and of the bar in each case."""


def make_background(surface: float, seed: int = 0):
    """``base(t)``: the view at time ``t`` with a plain ``surface`` above the band and the strip of
    1/f texture that scrolls at 60 px/s (linear interpolation between texels), shared by the
    probes."""
    rng = np.random.default_rng(seed)
    tex = 0.1 + 0.8 * spectral_noise(256, 2.5, 2.0, 1.5, rng)
    tex = np.tile(tex, (1, 4))  # 1024 px wide, periodic

    def base(t: float) -> np.ndarray:
        img = np.full((H, W), surface)
        img[SURFACE.stop : STRIP.start] = 0.3  # a band between surface and strip
        shift = t * 60.0
        i, f = int(np.floor(shift)), shift - np.floor(shift)
        moved = (1 - f) * np.roll(tex, -i, axis=1) + f * np.roll(tex, -i - 1, axis=1)
        img[STRIP] = moved[: STRIP.stop - STRIP.start, :W]
        return img

    return base


def make_scene(surface: float, bar: float, seed: int = 0):
    """``radiance_at(t)`` of the probe scene and the mask of the surface's inner pixels."""
    base = make_background(surface, seed)
    side = 40
    speed = (W + side) / (T_CROSS - 0.1)  # px/s: the bar has left 0.1 s before T_CROSS

    def radiance_at(t: float) -> np.ndarray:
        img = base(t)
        left = t * speed - side
        a, b = int(np.clip(np.floor(left), 0, W)), int(np.clip(np.ceil(left + side), 0, W))
        if b > a:
            cols = np.arange(a, b) + 0.5
            cover = np.clip(np.minimum(cols - left, left + side - cols), 0, 1)  # soft edges
            img[SURFACE, a:b] = surface * (1 - cover) + bar * cover
        return img

    mask = np.zeros((H, W), bool)
    mask[SURFACE.start + 4 : SURFACE.stop - 4, 4 : W - 4] = True
    return radiance_at, mask


def make_level_scene(surface: float, curtain: float, seed: int = 0, fill: bool = False):
    """``radiance_at(t)`` of the level probe and the masks of the curtain's half and the other.

    The curtain's right edge (soft, 2 px) moves from the left border to the middle of the view
    in ``T_CROSS - 0.1`` seconds and stays there, over :func:`make_background`.
    With ``fill`` the curtain covers the left half from the start (the simulator takes the first
    frame as its reference, so no event tells its level) and its edge sways by 12 px about the
    middle for the whole run: only a band around the edge sees events, and the masks keep 24 px
    away from it, so a network has the step only if it spreads the edge's level into the halves.
    """
    base = make_background(surface, seed)
    stop = W / 2
    speed = stop / (T_CROSS - 0.1)

    def radiance_at(t: float) -> np.ndarray:
        img = base(t)
        edge = stop + 12 * np.sin(2 * np.pi * 1.5 * t) if fill else min(t * speed, stop)
        cover = np.clip(edge - (np.arange(W) + 0.5) + 0.5, 0, 1)  # 1 left of the edge
        img[SURFACE] = surface * (1 - cover) + curtain * cover
        return img

    inner = np.zeros((H, W), bool)
    inner[SURFACE.start + 4 : SURFACE.stop - 4] = True
    cols, gap = np.arange(W), 24 if fill else 8
    covered = inner & (cols >= 8)[None] & (cols < int(stop) - gap)[None]
    other = inner & (cols >= int(stop) + gap)[None] & (cols < W - 8)[None]
    return radiance_at, covered, other


def simulate(radiance_at, contrast_sigma: float, t_end: float = T_END) -> Events:
    cam = EventCameraConfig(contrast_pos=0.2, contrast_neg=0.2, contrast_sigma=contrast_sigma,
                            noise_rate_hz=0.0, hot_pixel_fraction=0.0, refractory_us=0.0,
                            chunk_events=1 << 16)  # fmt: skip
    chunks: list[Events] = []
    simulate_event_stream(radiance_at, 0.0, t_end, cam, np.random.default_rng(1), chunks.append)
    return Events.concatenate(chunks)


REFERENCE = "direct integration, nominal threshold"
LEVEL_INTERVALS = ((0.0, 0.3), (0.3, 1.0), (1.0, 2.0), (2.0, 3.0))
"""Seconds after ``T_CROSS`` (the curtain parked 0.1 s before) for the level probe."""

INTERVALS = ((0.0, 0.2), (0.2, 0.6), (0.6, 1.0))
"""Seconds after ``T_CROSS`` (the bar left 0.1 s before) over which the residual is averaged."""


class DirectIntegration:
    """The reference: each pixel's events summed times the nominal threshold (0.2), log units."""

    def __init__(self) -> None:
        self.acc: np.ndarray | None = None

    def __call__(self, voxel: np.ndarray) -> np.ndarray:
        step = 0.2 * np.asarray(voxel, np.float64).sum(0)  # the bins of a pixel sum to its events
        self.acc = step if self.acc is None else self.acc + step
        return self.acc


def frames_after_cross(rec, ev: Events, n: int):
    """``(t, frame)`` for every window of ``n`` events that ends after ``T_CROSS`` (``t`` in
    seconds after it); ``rec`` runs over every window, so its state sees the whole stream."""
    for a in range(0, len(ev.t) - n + 1, n):
        sl = slice(a, a + n)
        out = np.asarray(rec(voxel_grid(ev.t[sl], ev.x[sl], ev.y[sl], ev.p[sl], 5, H, W)))
        t_end = ev.t[a + n - 1] * 1e-6
        if t_end > T_CROSS:
            yield t_end - T_CROSS, out


def interval_means(times: list[float], values: list[float], intervals) -> list[float]:
    """The mean of ``values`` over the times in each interval (NaN where none)."""
    t, v = np.array(times), np.array(values)
    return [float(v[(t >= a) & (t < b)].mean()) if ((t >= a) & (t < b)).any() else float("nan")
            for a, b in intervals]  # fmt: skip


def score(rec, ev: Events, mask: np.ndarray, n: int) -> list[float]:
    """Residual contrast of the surface averaged over each of :data:`INTERVALS`."""
    times, spans = [], []
    for t, out in frames_after_cross(rec, ev, n):
        lo, hi = np.percentile(out, [1, 99])
        p2, p98 = np.percentile(out[mask], [2, 98])
        times.append(t)
        spans.append((p98 - p2) / max(hi - lo, 1e-9))
    return interval_means(times, spans, INTERVALS)


def level_step(out: np.ndarray, covered: np.ndarray, other: np.ndarray) -> float:
    """Median of ``covered`` minus median of ``other``, over the frame's 1st-99th percentile span."""
    lo, hi = np.percentile(out, [1, 99])
    return float((np.median(out[covered]) - np.median(out[other])) / max(hi - lo, 1e-9))


def score_level(rec, ev: Events, covered, other, n: int, intervals) -> list[float]:
    """The step between the halves averaged over each interval after ``T_CROSS``."""
    steps = [(t, level_step(out, covered, other)) for t, out in frames_after_cross(rec, ev, n)]
    return interval_means([t for t, _ in steps], [v for _, v in steps], intervals)


def run_level(
    nets: dict,
    sigma: float,
    n: int,
    hold: float,
    fill: bool = False,
    ratio: float = 5.0,
    voxel_clip: float = 3.0,
) -> None:
    """Print the level probe's table (``fill``: the fill-in variant) for every network, the
    reference and the GT."""
    intervals = tuple((a, b) for a, b in LEVEL_INTERVALS if a < hold)
    low = 0.5 / ratio
    cases = {"dark curtain": (0.5, low), "light curtain": (low, 0.5)}
    rows: dict[str, list[list[float]]] = {}
    for surface, curtain in cases.values():
        sign = -1.0 if curtain < surface else 1.0
        radiance_at, covered, other = make_level_scene(surface, curtain, fill=fill)
        ev = simulate(radiance_at, sigma, T_CROSS + hold)
        for name, net in nets.items():
            rec = NetworkReconstructor(net, voxel_clip=voxel_clip)
            vals = score_level(rec, ev, covered, other, n, intervals)
            rows.setdefault(name, []).append([sign * v for v in vals])
        vals = score_level(DirectIntegration(), ev, covered, other, n, intervals)
        rows.setdefault(REFERENCE, []).append([sign * v for v in vals])
        gt = radiance_at(T_CROSS + hold)
        rows.setdefault("GT, log radiance", []).append(
            [sign * level_step(np.log(gt), covered, other)] * len(intervals)
        )
        rows.setdefault("GT, linear radiance", []).append(
            [sign * level_step(gt, covered, other)] * len(intervals)
        )
    cols = " | ".join(f"{a}-{b} s" for a, b in intervals)
    what = "24 px or more from the swaying edge (fill-in)" if fill else "after the curtain parked"
    print(f"\nthreshold spread {sigma}, windows of {n} events: step between the surface's halves "
          f"{what}, radiance ratio {ratio:g} (over the frame's 1-99 % span), mean of "
          f"{' and '.join(cases)}\n")  # fmt: skip
    print(f"| network | {cols} |")
    print("| --- " * (len(intervals) + 1) + "|")
    for name, r in rows.items():
        print(f"| {name} | " + " | ".join(f"{v:.3f}" for v in np.mean(r, axis=0)) + " |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ours", nargs="+", default=[str(ROOT / "resources/weights/evfirenet.pt")])
    ap.add_argument("--anchors", default=str(ROOT.parent / "shared" / "anchors"))
    ap.add_argument("--contrast-sigma", nargs="+", type=float, default=[0.03])
    ap.add_argument("--events-per-pixel", type=float, default=0.1)
    ap.add_argument("--voxel-clip", type=float, default=3.0)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--probes", nargs="+", choices=("bar", "level", "fill"),
                    default=["bar", "level", "fill"])  # fmt: skip
    ap.add_argument("--hold", type=float, default=3.0, help="seconds the level probe runs on")
    ap.add_argument("--level-ratio", type=float, default=5.0,
                    help="radiance ratio of the level probe's two halves (5: a step of 1.6 log "
                    "units, 8 thresholds of 0.2; 1.35: 0.3 log units, a weak wall-floor step)")  # fmt: skip
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    methods = {Path(p).stem: p for p in args.ours}
    for name, fname in (("FireNet", "firenet_1000.pth.tar"), ("FireNet+", "firenet_plus.pth")):
        if (Path(args.anchors) / "weights" / fname).is_file():
            methods[name] = str(Path(args.anchors) / "weights" / fname)
    nets = {k: load_checkpoint(v).net for k, v in methods.items()}
    n = int(round(args.events_per_pixel * W * H))
    for sigma in args.contrast_sigma:
        if "level" in args.probes:
            run_level(nets, sigma, n, args.hold, ratio=args.level_ratio, voxel_clip=args.voxel_clip)
        if "fill" in args.probes:
            run_level(nets, sigma, n, args.hold, True, args.level_ratio, args.voxel_clip)
        if "bar" not in args.probes:
            continue
        spans = {name: [] for name in nets}
        for surface, bar in CASES.values():
            radiance_at, mask = make_scene(surface, bar)
            ev = simulate(radiance_at, sigma)
            for name, net in nets.items():
                rec = NetworkReconstructor(net, voxel_clip=args.voxel_clip)
                spans[name].append(score(rec, ev, mask, n))
            spans.setdefault(REFERENCE, []).append(score(DirectIntegration(), ev, mask, n))
        cols = " | ".join(f"{a}-{b} s" for a, b in INTERVALS)
        print(f"\nthreshold spread {sigma}, windows of {n} events: residual contrast on the "
              f"surface after the bar left, mean of {' and '.join(CASES)}\n")  # fmt: skip
        print(f"| network | {cols} |")
        print("| --- " * (len(INTERVALS) + 1) + "|")
        for name, rows in spans.items():
            cells = " | ".join(f"{v:.3f}" for v in np.mean(rows, axis=0))
            print(f"| {name} | {cells} |")


if __name__ == "__main__":
    main()
