"""Stage packages hand out their stage module's names on first use.

`from pipeline.train import train` then works, while `import pipeline.train.constants` (what the CLI
needs for `--help`) does not pull in torch.
"""

from __future__ import annotations

import importlib


def stage_attribute(package: str, name: str) -> object:
    """`package.stage.<name>`, imported now; an AttributeError naming `package` when there is none."""
    if not name.startswith("__"):
        stage = importlib.import_module(f"{package}.stage")
        if hasattr(stage, name):
            return getattr(stage, name)
    raise AttributeError(f"module {package!r} has no attribute {name!r}")
