"""Checkpoints as a directory: `config.json` + `model.safetensors` (no pickle).

The normaliser's statistics are buffers of the model, so they are saved with the weights. Each file
is written to a temporary name and renamed into place, so an interrupted save leaves the previous
checkpoint intact.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

from models.cnep import CNEP
from models.config import CNEPConfig
from models.errors import ConfigError

FORMAT_VERSION = 1
CONFIG_FILE = "config.json"
WEIGHTS_FILE = "model.safetensors"


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def atomic_write(path: Path, data: bytes) -> None:
    """Write `data` to `path` through a temporary file in the same folder and a rename.

    The file gets the usual permissions (0666 less the umask), not mkstemp's private 0600.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        os.fchmod(fd, 0o666 & ~_umask())
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def save_checkpoint(model: CNEP, directory: str | Path, extra: dict | None = None) -> Path:
    """Save weights and config (plus any JSON-able `extra` entries) into `directory`."""
    from safetensors.torch import save

    directory = Path(directory)
    state = {k: v.detach().cpu().contiguous() for k, v in model.state_dict().items()}
    atomic_write(directory / WEIGHTS_FILE, save(state, metadata={"format_version": str(FORMAT_VERSION)}))
    config = {"format_version": FORMAT_VERSION, "model": model.config.to_dict(), **(extra or {})}
    atomic_write(directory / CONFIG_FILE, json.dumps(config, indent=2).encode())
    return directory


def read_checkpoint_config(directory: str | Path) -> dict:
    """The checkpoint's `config.json`, checked for its format version."""
    path = Path(directory) / CONFIG_FILE
    try:
        config = json.loads(path.read_text())
    except FileNotFoundError:
        raise ConfigError(f"{path}: no checkpoint config here; pass a directory written by `cnep train`.") from None
    except json.JSONDecodeError as exc:
        raise ConfigError(f"{path}: not valid JSON ({exc}).") from None
    version = config.get("format_version")
    if version != FORMAT_VERSION:
        raise ConfigError(
            f"{path}: checkpoint format_version {version!r} is not supported by this version "
            f"(supports {FORMAT_VERSION}); retrain or use the matching cnep-pipeline release."
        )
    return config


def load_checkpoint(directory: str | Path, device: str = "cpu") -> CNEP:
    """The model saved in `directory`, in eval mode."""
    from safetensors import SafetensorError
    from safetensors.torch import load_file

    directory = Path(directory)
    model = CNEP(CNEPConfig.from_dict(read_checkpoint_config(directory)["model"]))
    path = directory / WEIGHTS_FILE
    try:
        state = load_file(path, device=device)
    except (FileNotFoundError, SafetensorError, OSError) as exc:
        raise ConfigError(f"{path}: cannot read the weights ({exc}).") from None
    try:
        model.load_state_dict(state, strict=True)
    except RuntimeError as exc:
        raise ConfigError(f"{path}: weights do not match {CONFIG_FILE} ({exc}).") from None
    return model.to(device).eval()
