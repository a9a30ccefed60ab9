"""The pipeline stages (ingest, extract, train, replay, evaluate, demo) and the `cnep` CLI.

Each stage package hands out its public names (`from cnep.pipeline.train import train, TrainStageConfig`)
through `exports`: a name's module is imported when the name is first used (PEP 562). The stage modules
import torch, onnx or rerun, and the `cnep` command reads a stage package's light modules (its settings,
its constants) to answer `--help` and to check arguments before any of those load.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping, Sequence


def exports(package: str, modules: Mapping[str, Sequence[str]]) -> tuple[Callable[[str], object], list[str]]:
    """(`__getattr__`, `__all__`) of `package` handing out `modules`' names: module -> names defined there."""
    where = {name: module for module, names in modules.items() for name in names}

    def __getattr__(name: str) -> object:
        if name not in where:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(importlib.import_module(f"{package}.{where[name]}"), name)

    return __getattr__, sorted(where)
