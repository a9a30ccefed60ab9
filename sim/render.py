"""Headless rendering: MuJoCo's OpenGL backend chosen before `mujoco` is imported, and the one renderer reused.

MUJOCO_GL, when unset, becomes `egl` (GPU or Mesa's software rasteriser); `osmesa` is the other headless choice.
MuJoCo loads the backend when it is imported (`load_mujoco`, which `cnep.sim.require_extra` calls first), and makes a
context for a renderer (`Camera`): where either fails, `SimError` names the backend and the system package to install.
"""

from __future__ import annotations

import logging
import os
from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np

from cnep.sim.errors import SimError

if TYPE_CHECKING:
    import mujoco

BACKENDS = {"egl": "libegl1 (and libgl1-mesa-dri for software rendering)", "osmesa": "libosmesa6"}


def load_mujoco() -> ModuleType:
    """The `mujoco` module, imported with the backend MUJOCO_GL names; SimError naming it where that cannot load (a
    name MuJoCo does not know, a backend whose library is missing). No context is made here: one made before torch
    loads its libraries can crash the process (a renderer's, made later, cannot)."""
    logging.getLogger("OpenGL").setLevel(logging.WARNING)  # its INFO lines name each library it tried to load
    try:
        import mujoco
    except Exception as exc:  # MuJoCo and PyOpenGL raise several kinds of error for a backend that cannot load
        raise _unavailable(exc) from None
    return mujoco


def _unavailable(exc: Exception) -> SimError:
    """The error of a backend that cannot load or make a context (`exc`: what MuJoCo or PyOpenGL said)."""
    backend = os.environ.get("MUJOCO_GL", "egl")
    others = " or ".join(b for b in BACKENDS if b != backend)
    if backend not in BACKENDS:
        return SimError(f"MuJoCo cannot render headless with MUJOCO_GL={backend} ({exc}); set MUJOCO_GL to {others}")
    return SimError(
        f"MuJoCo cannot render headless with MUJOCO_GL={backend} ({type(exc).__name__}: {exc}); install "
        f"{BACKENDS[backend]}, or set MUJOCO_GL to {others}"
    )


class Camera:
    """A scene's fixed camera `name`: one `mujoco.Renderer` of the frame's size (height, width in pixels), reused
    for every frame."""

    def __init__(self, model: mujoco.MjModel, height: int, width: int, name: str) -> None:
        self.name = name
        try:
            self._renderer = load_mujoco().Renderer(model, height, width)
        except Exception as exc:  # the GL backends raise several kinds of error
            raise _unavailable(exc) from None

    def frame(self, data: mujoco.MjData) -> np.ndarray:
        """The camera's view of `data`: (height, width, 3) uint8 RGB, a new array."""
        self._renderer.update_scene(data, camera=self.name)
        return self._renderer.render()

    def close(self) -> None:
        self._renderer.close()
