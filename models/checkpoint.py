"""Checkpoints as a directory: `config.json` + `model.safetensors` (no pickle).

The normaliser's statistics are buffers of the model, so they are saved with the weights. Each file
is written to a temporary name and renamed into place, so an interrupted save leaves the previous
checkpoint intact. `config.json` carries the sha256 of its own content (`config_sha256`, over the
canonical JSON of every other entry), so an edited config (an expert count, the columns, the extractor
identity the features must match) is refused instead of silently changing what the model means.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from pathlib import Path

from cnep.models.cnep import CNEP
from cnep.models.config import CNEPConfig
from cnep.models.errors import ConfigError

FORMAT_VERSION = 1
CONFIG_FILE = "config.json"
WEIGHTS_FILE = "model.safetensors"
CHECKSUM_KEY = "config_sha256"


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
    config = json.loads(
        json.dumps({"format_version": FORMAT_VERSION, "model": model.config.to_dict(), **(extra or {})})
    )
    config[CHECKSUM_KEY] = config_checksum(config)  # of the config as read back (tuples are lists there)
    atomic_write(directory / CONFIG_FILE, json.dumps(config, indent=2).encode())
    return directory


def read_checkpoint_config(directory: str | Path) -> dict:
    """The checkpoint's `config.json`, checked for its format version."""
    path = Path(directory) / CONFIG_FILE
    if Path(directory).is_file():
        raise ConfigError(
            f"{directory}: is a file; pass the checkpoint folder written by `cnep train` (the one "
            f"holding {CONFIG_FILE} and {WEIGHTS_FILE})."
        )
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
    saved = config.pop(CHECKSUM_KEY, None)
    if saved != config_checksum(config):
        state = "has no checksum" if saved is None else "does not match its checksum"
        raise ConfigError(
            f"{path}: the checkpoint config {state}: it was edited after training (or written by an "
            f"older cnep); retrain with `cnep train` instead of editing it."
        )
    return config


def config_checksum(config: dict) -> str:
    """sha256 (hex) of the canonical JSON of `config` (keys sorted, compact), its own checksum entry left out."""
    entries = {key: value for key, value in config.items() if key != CHECKSUM_KEY}
    text = json.dumps(entries, sort_keys=True, separators=(",", ":"), ensure_ascii=True)
    return hashlib.sha256(text.encode()).hexdigest()


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
    except RuntimeError as exc:  # torch lists every mismatched tensor over many lines: the first one says enough
        first = next((line.strip() for line in str(exc).splitlines()[1:] if line.strip()), str(exc))
        raise ConfigError(
            f"{path}: weights do not match {CONFIG_FILE} ({first}); retrain, or restore the "
            f"{CONFIG_FILE} written with these weights."
        ) from None
    return model.to(device).eval()
