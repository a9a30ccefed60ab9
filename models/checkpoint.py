"""Checkpoints as a directory: `config.json` + `model.safetensors` (no pickle).

The normaliser's statistics are buffers of the model, so they are saved with the weights. Each file
is written to a temporary name and renamed into place (cnep.outputs), so an interrupted save leaves the
previous checkpoint intact. `config.json` carries the sha256 of its own content (`config_sha256`, over the
canonical JSON of every other entry), so an edited config (an expert count, the columns, the extractor
identity the features must match) is refused instead of silently changing what the model means.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import TYPE_CHECKING

from cnep.models.config import CNEPConfig
from cnep.models.errors import ConfigError
from cnep.outputs import staged
from cnep.runtime.jsonfile import read_json

if TYPE_CHECKING:
    from cnep.models.cnep import CNEP

FORMAT_VERSION = 1
CONFIG_FILE = "config.json"
WEIGHTS_FILE = "model.safetensors"
CHECKSUM_KEY = "config_sha256"
_JSON_KINDS = {
    list: "a JSON array",
    type(None): "JSON null",
    str: "a JSON string",
    bool: "a JSON boolean",
    int: "a JSON number",
    float: "a JSON number",
}


def save_checkpoint(model: CNEP, directory: str | Path, extra: dict | None = None, record: bool = False) -> Path:
    """Save weights and config (plus any JSON-able `extra` entries) into `directory`, the two files renamed into place
    together; with `record`, as outputs of the command writing (cnep.outputs.staged: checked, renamed and recorded
    together)."""
    from safetensors.torch import save

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    state = {k: v.detach().cpu().contiguous() for k, v in model.state_dict().items()}
    config = json.loads(
        json.dumps({"format_version": FORMAT_VERSION, "model": model.config.to_dict(), **(extra or {})})
    )
    config[CHECKSUM_KEY] = config_checksum(config)  # of the config as read back (tuples are lists there)
    with staged(record=record) as staging:
        staging.write(directory / WEIGHTS_FILE, save(state, metadata={"format_version": str(FORMAT_VERSION)}))
        staging.write(directory / CONFIG_FILE, json.dumps(config, indent=2).encode())
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
        config = read_json(path)
    except FileNotFoundError:
        raise ConfigError(f"{path}: no checkpoint config here; pass a directory written by `cnep train`.") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read it ({exc.strerror}).") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: not a text file; pass a directory written by `cnep train`.") from None
    except ValueError as exc:
        raise ConfigError(f"{path}: not valid JSON ({exc}).") from None
    if not isinstance(config, dict):
        raise ConfigError(
            f"{path}: holds {_JSON_KINDS.get(type(config), 'a JSON value')}, not the checkpoint's settings (a JSON "
            f"object); pass a directory written by `cnep train`, or retrain."
        )
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


def checkpoint_model_config(directory: str | Path) -> CNEPConfig:
    """The model settings (`model`) of the checkpoint's config.json; ConfigError naming the file if they are missing or
    malformed."""
    path = Path(directory) / CONFIG_FILE
    model = read_checkpoint_config(directory).get("model")
    if not isinstance(model, dict):
        raise ConfigError(f"{path}: no model settings (a JSON object `model`); retrain with `cnep train`.")
    try:
        return CNEPConfig.from_dict(model)
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None
    except (TypeError, ValueError, KeyError, AttributeError, OverflowError) as exc:
        raise ConfigError(f"{path}: malformed model settings ({exc}); retrain with `cnep train`.") from None


def config_checksum(config: dict) -> str:
    """sha256 (hex) of the canonical JSON of `config` (keys sorted, compact), its own checksum entry left out."""
    entries = {key: value for key, value in config.items() if key != CHECKSUM_KEY}
    text = json.dumps(entries, sort_keys=True, separators=(",", ":"), ensure_ascii=True)
    return hashlib.sha256(text.encode()).hexdigest()


def load_checkpoint(directory: str | Path, device: str = "cpu") -> CNEP:
    """The model saved in `directory`, in eval mode."""
    from safetensors import SafetensorError
    from safetensors.torch import load_file

    from cnep.models.cnep import CNEP  # torch: here, so that reading a checkpoint's config.json needs none

    directory = Path(directory)
    model = CNEP(checkpoint_model_config(directory))
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
