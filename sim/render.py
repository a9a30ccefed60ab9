"""Headless rendering: MuJoCo's OpenGL backend chosen before `mujoco` is imported, and the one renderer reused.

MUJOCO_GL, when unset, becomes `egl` (GPU or Mesa's software rasteriser); `osmesa` is the other headless choice.
When neither can make a context, `SimError` names the system package to install.
"""

from __future__ import annotations

import os

import mujoco
import numpy as np

from cnep.sim.errors import SimError

BACKENDS = {"egl": "libegl1 (and libgl1-mesa-dri for software rendering)", "osmesa": "libosmesa6"}


class Camera:
    """A scene's fixed camera `name`: one `mujoco.Renderer` of the frame's size (height, width in pixels), reused
    for every frame."""

    def __init__(self, model: mujoco.MjModel, height: int, width: int, name: str) -> None:
        self.name = name
        try:
            self._renderer = mujoco.Renderer(model, height, width)
        except Exception as exc:  # the GL backends raise several kinds of error
            backend = os.environ.get("MUJOCO_GL", "egl")
            package = BACKENDS.get(backend, "the OpenGL library MUJOCO_GL names")
            raise SimError(
                f"MuJoCo cannot render headless with MUJOCO_GL={backend} ({exc}); install {package}, or set "
                f"MUJOCO_GL to {' or '.join(b for b in BACKENDS if b != backend)}"
            ) from None

    def frame(self, data: mujoco.MjData) -> np.ndarray:
        """The camera's view of `data`: (height, width, 3) uint8 RGB, a new array."""
        self._renderer.update_scene(data, camera=self.name)
        return self._renderer.render()

    def close(self) -> None:
        self._renderer.close()
