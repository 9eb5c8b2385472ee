"""Simulation stages: a dataset's scene rendered through the event camera and the conventional camera.

Each stage builds the scene of one dataset (:func:`evdense.sim.scene.load_scene`), renders it along
the trajectory (:class:`evdense.sim.render.Renderer`) and writes the camera's output:

- :func:`simulate_events` -> ``results/{dataset}/events/events.h5`` (canonical event file);
- :func:`simulate_conventional` -> ``results/{dataset}/conventional/`` (``frames/`` + ``settings.json``).

Time runs from 0 to the recording's duration (``scene.trajectory.duration``, seconds), the same
clock as the ground-truth trajectory; event timestamps are microseconds on that clock.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from evdense import __version__
from evdense.log import get_logger
from evdense.sim.conventional import ConventionalCameraConfig, simulate_frames
from evdense.sim.esim import EventCameraConfig, RadianceFn, write_event_stream

log = get_logger("sim.simulate")

# Independent random streams of one dataset seed: scene textures use their own.
_EVENT_STREAM = 1
_CONVENTIONAL_STREAM = 2


def _scene_radiance(
    dataset_conf: dict, sim_conf: dict | None, stream: int
) -> tuple[Any, RadianceFn, float, np.random.Generator]:
    """The dataset's scene, its ``radiance_at(t)`` ``(H, W)`` float32 function, its duration in
    seconds, and the random stream ``stream`` of the dataset's seed."""
    from evdense.sim.render import Renderer
    from evdense.sim.scene import load_scene

    scene = load_scene(dataset_conf, sim_conf)
    rng = np.random.default_rng([int(scene.dataset["seed"]), stream])
    return scene, Renderer(scene).radiance_at, float(scene.trajectory.duration), rng


def _provenance(scene: Any, sim_conf: dict | None, section: str) -> dict[str, Any]:
    return {
        "generator": f"evdense {__version__} evdense.sim.simulate",
        "scene": scene.name,
        "dataset": scene.dataset,
        section: (sim_conf or {}).get(section, {}),
        "render": (sim_conf or {}).get("render", {}),
    }


def simulate_events(dataset_conf: dict, sim_conf: dict | None, out_path: str | Path) -> Path:
    """Simulate the event camera over a synthetic dataset and write ``out_path`` (canonical HDF5).

    ``dataset_conf``: one entry of ``config["datasets"]`` (with ``scene``); ``sim_conf``:
    ``config["simulator"]`` (sections ``render`` and ``event_camera``). Events span
    ``[0, duration]`` seconds of the recording; the sensor is the scene camera's ``(H, W)``.
    Raises ``ValueError`` naming the key for a bad config.
    """
    out_path = Path(out_path)
    conf = EventCameraConfig.from_dict((sim_conf or {}).get("event_camera"))
    scene, radiance_at, duration, rng = _scene_radiance(dataset_conf, sim_conf, _EVENT_STREAM)
    log.info(
        "simulating events: scene %s, %.3f s, %dx%d pixels, C+ %.3f C- %.3f",
        scene.name,
        duration,
        scene.camera.width,
        scene.camera.height,
        conf.contrast_pos,
        conf.contrast_neg,
    )
    write_event_stream(
        radiance_at,
        0.0,
        duration,
        conf,
        rng,
        out_path,
        provenance=_provenance(scene, sim_conf, "event_camera"),
        attrs={"scene": scene.name, "duration_s": duration, "camera": scene.camera.to_dict()},
    )
    return out_path


def simulate_conventional(dataset_conf: dict, sim_conf: dict | None, out_dir: str | Path) -> Path:
    """Simulate the conventional camera over a synthetic dataset into ``out_dir``.

    Writes ``out_dir/frames/000000.png ...``, ``out_dir/frames/timestamps.txt`` (``index t_seconds``,
    middle of exposure) and ``out_dir/settings.json``, atomically (a ``.partial`` folder renamed).
    ``sim_conf`` sections read: ``render`` and ``conventional_camera``.
    """
    out_dir = Path(out_dir)
    conf = ConventionalCameraConfig.from_dict((sim_conf or {}).get("conventional_camera"))
    scene, radiance_at, duration, rng = _scene_radiance(
        dataset_conf, sim_conf, _CONVENTIONAL_STREAM
    )
    log.info(
        "simulating conventional frames: scene %s, %.3f s at %.1f fps, exposure %.1f ms",
        scene.name,
        duration,
        conf.fps,
        conf.exposure * 1e3,
    )
    simulate_frames(
        radiance_at,
        duration,
        conf,
        rng,
        out_dir,
        extra={
            "provenance": _provenance(scene, sim_conf, "conventional_camera"),
            "sensor": scene.camera.to_dict(),
        },
    )
    return out_dir
