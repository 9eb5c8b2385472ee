"""Our event-camera simulator: static textured scenes with ground truth (scene, trajectory, render,
groundtruth), and the event and conventional cameras built on the renderer."""

from evdense.sim.presets import PRESETS
from evdense.sim.render import Renderer, RenderOutput
from evdense.sim.scene import Scene, load_scene
from evdense.sim.trajectory import Trajectory

__all__ = ["PRESETS", "RenderOutput", "Renderer", "Scene", "Trajectory", "load_scene"]
