"""The simulated world of ``teach --sim`` and ``repeat --sim``: what a camera would see.

* :mod:`.world` -- the camera on its robot and the target on the wall, as teach and fit
  files describe them, with the exact projection;
* :mod:`.poster` -- the target's picture as a raster with an anti-aliasing pyramid;
* :mod:`.render` -- camera frames of the poster from a robot pose (exposure, blur, noise,
  lens distortion), and the renderer of a world (:func:`make_renderer`);
* :mod:`.scene` -- the world of a repeat: the taught one, or one built from real footage at
  an assumed depth, with the taught pose at any time;
* :mod:`.simulated_camera` -- the repeat's simulated camera (rendered images or projected points)
  with its faults;
* :mod:`.closed_loop` -- the simulated closed loop (sense, step, move) and a run set up for it.

Nothing here reads or writes MCAP files; the stages do.
"""

from .simulated_camera import CameraSettings, SimulatedCamera
from .closed_loop import Simulation
from .poster import PosterRaster, build_pyramid
from .render import RenderSettings, SceneRenderer, load_texture, make_renderer
from .scene import Scene, simulation_world, world_from_reference, world_point_identity

__all__ = [
    "CameraSettings",
    "PosterRaster",
    "RenderSettings",
    "Scene",
    "SceneRenderer",
    "SimulatedCamera",
    "Simulation",
    "build_pyramid",
    "load_texture",
    "make_renderer",
    "simulation_world",
    "world_from_reference",
    "world_point_identity",
]
