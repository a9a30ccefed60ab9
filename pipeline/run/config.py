"""The run stage's settings (`RunConfig`): the defaults of `cnep run`, and of `run()` from Python.

Importable without torch or rerun: the `cnep run` command builds its config (and so checks its options)
and checks the policy's folder (`policy_kind`) before it loads the stage.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from cnep.models.checkpoint import CONFIG_FILE, read_checkpoint_config
from cnep.models.config import ConditioningOverrides, setting
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.inputs import coerce_paths
from cnep.pipeline.train.config import checkpoint_conditioning
from cnep.runtime.conditioning import ConditioningPolicy
from cnep.runtime.constants import DEFAULT_BACKEND, DEFAULT_PRECISION, DEFAULT_WAYPOINTS, MANIFEST_FILE
from cnep.runtime.timebase import TimeBase

EXPORTED, CHECKPOINT = "exported", "checkpoint"


@dataclass(frozen=True)
class RunConfig:
    """What `run` runs and where it writes.

    policy: exported folder or checkpoint folder; recordings: demonstration files or folders (read only); out:
    the .rrd (None: `connect` only); connect: a live viewer's URL; extractor: weights of a checkpoint's
    training features (None: ImageNet); precision, backend: the exported folder's feature graph and runner;
    threads: intra-op threads (None: one per core); waypoints: future steps predicted per step; time_base: seconds ->
    phase (None: the policy's own); conditioning: the conditioning settings that replace the policy's own (those
    given); realtime: pace the steps at the recording's rate (False: as fast as possible); force: replace existing
    outputs.
    """

    policy: Path
    recordings: tuple[Path, ...]
    out: Path | None = None
    connect: str | None = None
    extractor: Path | None = None
    precision: str = setting(
        DEFAULT_PRECISION, "an exported policy's feature graph; int8 needs a folder exported with --int8"
    )
    backend: str = setting(DEFAULT_BACKEND, "what runs the exported graphs; openvino where it is installed")
    threads: int | None = setting(None, "intra-op threads of the policy's graphs")
    waypoints: int = setting(DEFAULT_WAYPOINTS, "future steps predicted per step")
    time_base: TimeBase | None = None
    conditioning: ConditioningOverrides = field(default_factory=ConditioningOverrides)
    realtime: bool = True
    force: bool = False
    quiet: bool = False

    def __post_init__(self) -> None:
        coerce_paths(self)
        if not self.recordings:
            raise PipelineError("run needs at least one demonstration recording")
        if (self.out is None) == (self.connect is None):
            raise PipelineError("run writes to exactly one place: an .rrd file (--out) or a live viewer")
        if self.out is not None and Path(self.out).suffix != ".rrd":
            raise PipelineError(f"{self.out}: the run's output must be a .rrd file")
        if self.waypoints < 1 or (self.threads is not None and self.threads < 1):
            raise PipelineError(f"waypoints and threads must be >= 1, got {self.waypoints} and {self.threads}")


def policy_kind(path: Path) -> str:
    """EXPORTED for a folder of `cnep export` (runs without torch), CHECKPOINT for one of `cnep train`; PipelineError
    for anything else."""
    path = Path(path)
    if (path / MANIFEST_FILE).is_file():
        return EXPORTED
    if (path / CONFIG_FILE).is_file():
        return CHECKPOINT
    what = (
        "no such folder"
        if not path.exists()
        else "is a file"
        if not path.is_dir()
        else f"neither an exported policy ({MANIFEST_FILE}) nor a checkpoint ({CONFIG_FILE}) here"
    )
    raise PipelineError(f"{path}: {what}; give a folder written by `cnep export` or `cnep train`")


def own_conditioning(path: Path) -> ConditioningPolicy:
    """The conditioning the policy in folder `path` runs with unless given another: its manifest's (exported) or its
    config.json's (checkpoint); read without torch."""
    path = Path(path)
    if policy_kind(path) == EXPORTED:
        from cnep.runtime.manifest import read_manifest

        return read_manifest(path).spec.conditioning
    return checkpoint_conditioning(read_checkpoint_config(path), path / CONFIG_FILE)


def conditioning_line(own: ConditioningPolicy, given: ConditioningOverrides, whose: str = "the policy's") -> str:
    """One line saying the conditioning a policy whose own is `own` runs with when `given` replaces some of it, and
    for each setting given, what it replaced (whose: the policy's, the checkpoint's)."""
    replaced = given.given()
    said = [
        f"{name.replace('_', ' ')} {value}" + (f" (given; {whose} {getattr(own, name)})" if name in replaced else "")
        for name, value in given.applied(own).to_dict().items()
    ]
    return "conditioning: " + ", ".join(said)
