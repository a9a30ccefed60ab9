"""What `cnep sim` needs installed besides the core, checked before any work (`require_extras`): the extras a run or an
evaluation will import, named in one line with the command that installs them. Importable without torch or MuJoCo.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

from cnep.pipeline.errors import PipelineError
from cnep.pipeline.run.config import EXPORTED, policy_kind
from cnep.pipeline.sim.config import EvalConfig, PickPlaceConfig, SimConfig

# extra (pyproject.toml's optional dependencies) -> the modules of it that `cnep sim` imports
MODULES = {
    "sim": ("mujoco", "gymnasium"),  # the simulator
    "onnx": ("onnx", "onnxruntime"),  # the export's graphs, and the exported policies' runtime
    "baselines": ("movement_primitives", "gmr"),  # ProMP, GMM-GMR
}


def needed_extras(config: SimConfig | PickPlaceConfig | EvalConfig) -> tuple[str, ...]:
    """The extras the command `config` configures will import: the simulator always; a run (`cnep sim TASK`) exports
    its policies and runs them on ONNX Runtime, and with `baselines` fits them; an evaluation of an exported policy
    runs it on ONNX Runtime (a checkpoint runs on torch)."""
    if isinstance(config, EvalConfig):
        return ("sim", "onnx") if policy_kind(Path(config.policy)) == EXPORTED else ("sim",)
    return ("sim", "onnx", "baselines") if config.baselines else ("sim", "onnx")


def require_extras(config: SimConfig | PickPlaceConfig | EvalConfig, command: str) -> None:
    """PipelineError, one line naming what `command` misses and how to install it, when an extra it needs is not
    installed; then cnep.sim.SimError, one line naming MUJOCO_GL, when MuJoCo cannot load the backend it names."""
    absent = {
        extra: [m for m in MODULES[extra] if importlib.util.find_spec(m) is None] for extra in needed_extras(config)
    }
    missing = {extra: modules for extra, modules in absent.items() if modules}
    if not missing:
        from cnep.sim import require_extra  # loads MuJoCo: only once the extras are known to be there

        return require_extra()
    extras = f"the {' and '.join(missing)} extra{'s' if len(missing) > 1 else ''}"
    modules = ", ".join(m for ms in missing.values() for m in ms)
    hint = ", or leave the baselines out: --no-baselines" if "baselines" in missing else ""
    raise PipelineError(
        f"{command} needs {extras} ({modules} not installed): pip install 'cnep-pipeline[{','.join(missing)}]'{hint}"
    )
