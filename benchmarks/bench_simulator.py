"""Simulator speed and convergence.

1. Speed: 1 s of the fast default scene (preset ``room`` at ``--speed``, default 4) simulated end to
   end: ground truth, events and conventional frames, through the same
   stage functions the workflow calls. Prints seconds per stage, renders per second and events per
   second.
2. Convergence: for each preset, the events of ``--window`` seconds with the adaptive render step,
   and with every step halved (``step_subdivisions = 2``), noise off. Prints the relative change of
   the event count and the relative L1 change of the per-pixel event-count map (target < 5 %).

Run: ``PYTHONPATH=src .venv/bin/python benchmarks/bench_simulator.py [--speed 4] [--window 0.25]``
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from evdense.events.container import EventFile, Events
from evdense.log import setup_logging
from evdense.sim.esim import EventCameraConfig, simulate_event_stream
from evdense.sim.groundtruth import write_groundtruth
from evdense.sim.render import Renderer
from evdense.sim.scene import load_scene
from evdense.sim.simulate import simulate_conventional, simulate_events

PRESETS = ("room", "desk", "facade")


def bench_speed(preset: str, speed: float, seconds: float, sim_conf: dict) -> None:
    dataset = {"scene": preset, "speed": speed, "duration": seconds * speed, "seed": 0}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        times: dict[str, float] = {}
        t0 = time.perf_counter()
        write_groundtruth(dataset, sim_conf, tmp / "gt")
        times["groundtruth"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        simulate_events(dataset, sim_conf, tmp / "events.h5")
        times["events"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        simulate_conventional(dataset, sim_conf, tmp / "conventional")
        times["conventional"] = time.perf_counter() - t0
        with EventFile(tmp / "events.h5") as ef:
            stats = ef.attrs["simulation_stats"]
            n_events = ef.num_events
        settings = json.loads((tmp / "conventional" / "settings.json").read_text())
    total = sum(times.values())
    print(f"\n== speed: {seconds:g} s of '{preset}' at speed {speed:g} ==")
    for k, v in times.items():
        print(f"  {k:13s} {v:7.1f} s")
    print(f"  {'total':13s} {total:7.1f} s   (target <= 60 s)")
    ev_t = times["events"]
    print(
        f"  events: {n_events} ({n_events / seconds:.0f} ev/s of recording, {n_events / ev_t:.0f} ev/s of compute), "
        f"{stats['renders']} renders ({stats['renders'] / ev_t:.1f} renders/s), {stats['steps']} steps of "
        f"{stats['min_step_s'] * 1e6:.0f}-{stats['max_step_s'] * 1e6:.0f} us, {stats['rejected_steps']} rejected"
    )
    cv_t = times["conventional"]
    subs = [f["subframes"] for f in settings["frames"]]
    print(
        f"  conventional: {settings['num_frames']} frames, {settings['renders']} renders "
        f"({settings['renders'] / cv_t:.1f} renders/s), sub-renders per frame {min(subs)}-{max(subs)}, "
        f"saturated {max(f['saturated'] for f in settings['frames']) * 100:.2f} % max"
    )


def run_window(radiance_at, window: float, conf: EventCameraConfig) -> tuple[Events, dict]:
    """All events of ``window`` seconds (kept in memory: use short windows) and run figures."""
    parts: list[Events] = []
    t0 = time.perf_counter()
    stats = simulate_event_stream(
        radiance_at, 0.0, window, conf, np.random.default_rng(0), parts.append
    )
    return Events.concatenate(parts), {
        "renders": stats.renders,
        "seconds": time.perf_counter() - t0,
    }


def compare(a: Events, b: Events, width: int, n_pix: int) -> tuple[float, float, float]:
    """Relative count change, relative L1 change of the per-pixel count map, and the median
    timestamp change (us) over pixels that have the same number of events in both runs."""
    pa = a.y.astype(np.int64) * width + a.x
    pb = b.y.astype(np.int64) * width + b.x
    ma, mb = np.bincount(pa, minlength=n_pix), np.bincount(pb, minlength=n_pix)
    d_count = abs(len(a) - len(b)) / max(len(b), 1)
    d_map = np.abs(ma - mb).sum() / max(len(b), 1)
    same = (ma == mb) & (ma > 0)
    sel_a, sel_b = same[pa], same[pb]
    oa = np.lexsort((a.t[sel_a], pa[sel_a]))
    ob = np.lexsort((b.t[sel_b], pb[sel_b]))
    dt = np.abs(a.t[sel_a][oa] - b.t[sel_b][ob])  # aligned: same pixels, same counts, both sorted
    return d_count, d_map, float(np.median(dt)) if len(dt) else 0.0


def bench_convergence(
    speed: float, window: float, sim_conf: dict, presets: tuple[str, ...] = PRESETS
) -> None:
    print(
        f"\n== convergence: {window:g} s per preset at speed {speed:g}, render step vs. step / 2, noise off =="
    )
    base = dict(sim_conf.get("event_camera") or {})
    base.update(noise_rate_hz=0.0, hot_pixel_fraction=0.0)
    for preset in presets:
        scene = load_scene({"scene": preset, "speed": speed, "seed": 0}, sim_conf)
        renderer = Renderer(scene)
        w, h = scene.camera.width, scene.camera.height
        # The window is taken from the middle of the path, where the camera moves at full speed.
        t_mid = max(0.0, scene.trajectory.duration / 2 - window / 2)

        def radiance_at(t: float, t_mid=t_mid, renderer=renderer) -> np.ndarray:
            return renderer.radiance_at(t_mid + t)

        a, sa = run_window(radiance_at, window, EventCameraConfig.from_dict(base))
        b, sb = run_window(
            radiance_at, window, EventCameraConfig.from_dict({**base, "step_subdivisions": 2})
        )
        d_count, d_map, d_t = compare(a, b, w, w * h)
        ok = "ok" if d_count < 0.05 and d_map < 0.05 else "MISSED"
        print(
            f"  {preset:7s} events {len(a):8d} vs {len(b):8d}: count change {d_count * 100:5.2f} %, "
            f"per-pixel map L1 change {d_map * 100:5.2f} %  [{ok}], median timestamp change {d_t:.0f} us; "
            f"{sa['renders'] / window:.0f} vs {sb['renders'] / window:.0f} renders per second of recording "
            f"({sa['seconds']:.1f} + {sb['seconds']:.1f} s)"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--preset", default="room")
    ap.add_argument("--speed", type=float, default=4.0, help="speed factor of the fast scene")
    ap.add_argument(
        "--seconds", type=float, default=1.0, help="recording length for the speed figure"
    )
    ap.add_argument(
        "--window", type=float, default=0.25, help="seconds simulated per preset for convergence"
    )
    ap.add_argument("--skip-speed", action="store_true")
    ap.add_argument("--skip-convergence", action="store_true")
    ap.add_argument(
        "--presets", default=",".join(PRESETS), help="comma-separated presets for convergence"
    )
    ap.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", help="event_camera override"
    )
    args = ap.parse_args()
    setup_logging(None)
    overrides = {
        k: int(v) if v.isdigit() else float(v) for k, v in (kv.split("=", 1) for kv in args.set)
    }
    sim_conf: dict = {"event_camera": overrides} if overrides else {}
    if not args.skip_speed:
        bench_speed(args.preset, args.speed, args.seconds, sim_conf)
    if not args.skip_convergence:
        bench_convergence(args.speed, args.window, sim_conf, tuple(args.presets.split(",")))


if __name__ == "__main__":
    main()
