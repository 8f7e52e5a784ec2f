"""The simulated world of ``teach --sim`` and ``repeat --sim``: world, poster raster,
renderer, the repeat's scene and camera, and the closed loop. No MCAP I/O (the stages do it)."""

from .simulated_camera import CameraSettings, SimulatedCamera
from .closed_loop import Simulation
from .poster import PosterRaster
from .render import RenderSettings, SceneRenderer, make_renderer
from .scene import Scene, simulation_world

__all__ = [
    "CameraSettings", "PosterRaster", "RenderSettings", "Scene", "SceneRenderer", "SimulatedCamera", "Simulation",
    "make_renderer", "simulation_world",
]
