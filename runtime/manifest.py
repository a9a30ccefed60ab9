"""The manifest of an exported policy folder (`manifest.json`): what each file is, and the policy's spec.

    format            "cnep-policy"; format_version: FORMAT_VERSION (unknown versions are refused)
    producer          the cnep-pipeline that exported it
    spec              runtime.spec.PolicySpec.to_dict(): model row, normaliser, state mapping, time base
    extractor         identity of the features the model was trained on ({} for a model without a camera)
    features          precision -> {"file": ONNX graph, "identity": the identity of the features it makes}
    graphs            {"encoder": ENCODER_FILE, "decoder": DECODER_FILE}
    checkpoint        {"config_sha256": the checkpoint's own checksum, "layout": its layout preset}
    files             relative path -> sha256 (hex) of every file in the folder but the manifest

docs/reference/export-format.md describes every entry for users.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path

from cnep.runtime.constants import FORMAT_VERSION, MANIFEST_FILE, MANIFEST_FORMAT
from cnep.runtime.errors import PolicyError
from cnep.runtime.spec import PolicySpec

HASH_BLOCK = 1 << 20  # bytes read at a time when hashing a file


@dataclass(frozen=True)
class Manifest:
    """The parsed manifest (see the module docstring for each entry)."""

    spec: PolicySpec
    graphs: dict[str, str]
    features: dict[str, dict] = field(default_factory=dict)
    extractor: dict[str, str] = field(default_factory=dict)
    checkpoint: dict[str, str] = field(default_factory=dict)
    producer: str = ""
    files: dict[str, str] = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {
            "format": MANIFEST_FORMAT,
            "format_version": FORMAT_VERSION,
            "producer": self.producer,
            "spec": self.spec.to_dict(),
            "extractor": self.extractor,
            "features": self.features,
            "graphs": self.graphs,
            "checkpoint": self.checkpoint,
            "files": self.files,
        }

    @classmethod
    def from_dict(cls, data: dict, path: Path) -> Manifest:
        """The manifest in `data` (read from `path`, named in errors), checked for its format and version."""
        if not isinstance(data, dict) or data.get("format") != MANIFEST_FORMAT:
            raise PolicyError(f"{path}: not a cnep policy manifest (no format {MANIFEST_FORMAT!r}); run `cnep export`")
        version = data.get("format_version")
        if version != FORMAT_VERSION:
            raise PolicyError(
                f"{path}: policy format_version {version!r} is not supported by this runtime (supports "
                f"{FORMAT_VERSION}); export the checkpoint again with this cnep-pipeline, or install the runtime "
                f"that came with the export (pip install {path.parent}/runtime)"
            )
        try:
            spec = PolicySpec.from_dict(data["spec"])
            return cls(
                spec=spec,
                graphs=dict(data["graphs"]),
                features=dict(data["features"]),
                extractor=dict(data["extractor"]),
                checkpoint=dict(data["checkpoint"]),
                producer=str(data["producer"]),
                files=dict(data["files"]),
            )
        except PolicyError as exc:
            raise PolicyError(f"{path}: {exc}") from None
        except (KeyError, TypeError, ValueError) as exc:
            raise PolicyError(f"{path}: the manifest lacks or mangles {exc}; export the checkpoint again") from None

    def verified(self, folder: Path, name: str) -> Path:
        """The path of file `name` in `folder`, after checking it against the manifest's sha256."""
        path = folder / name
        expected = self.files.get(name)
        if expected is None:
            raise PolicyError(f"{folder / MANIFEST_FILE}: lists no hash for {name}; export the checkpoint again")
        try:
            actual = file_sha256(path)
        except OSError as exc:
            raise PolicyError(f"{path}: cannot read it ({exc.strerror}); export the checkpoint again") from None
        if actual != expected:
            raise PolicyError(
                f"{path}: sha256 {actual[:12]}... differs from the manifest's {expected[:12]}...: the file was "
                f"changed or damaged after export; export the checkpoint again"
            )
        return path


def read_manifest(folder: str | Path) -> Manifest:
    """The manifest of the exported policy in `folder`."""
    folder = Path(folder)
    path = folder / MANIFEST_FILE
    if not path.is_file():
        hint = (
            " (this is a checkpoint folder: export it with `cnep export`)" if (folder / "config.json").is_file() else ""
        )
        raise PolicyError(f"{folder}: no {MANIFEST_FILE} here{hint}; give a folder written by `cnep export`")
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise PolicyError(f"{path}: cannot read the manifest ({exc}); export the checkpoint again") from None
    return Manifest.from_dict(data, path)


def file_sha256(path: str | Path) -> str:
    """sha256 of the file's bytes (hex)."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(HASH_BLOCK):
            digest.update(block)
    return digest.hexdigest()
