"""The manifest of an exported policy folder (`manifest.json`): what each file is, and the policy's spec.

    format            "cnep-policy"; format_version: FORMAT_VERSION (READ_VERSIONS are read, others refused)
    producer          the cnep-pipeline that exported it
    spec              runtime.spec.PolicySpec.to_dict(): model row, normaliser, state mapping, time base,
                      conditioning, gripper command, the tasks and the camera (key, frame size) trained on
    extractor         identity of the features the model was trained on ({} for a model without a camera)
    features          precision -> {"file": ONNX graph, "identity": the identity of the features it makes}
    graphs            {"encoder": ENCODER_FILE, "decoder": DECODER_FILE}
    checkpoint        {"config_sha256": the checkpoint's own checksum, "preset": its layout preset}
    files             relative path -> sha256 (hex) of every file in the folder but the manifest

The folder is closed: every file the manifest names is a plain file name in the folder (`runtime/` source files: a
relative path of plain names under it), checked by `read_manifest`, and the folder holds nothing but the
manifest, the files it lists and `runtime/` (which the loader never reads), checked by `check_closed`; `load_policy`
runs both before it opens any other file. docs/reference/export-format.md
describes every entry, and what the runtime trusts, for users.
"""

from __future__ import annotations

import hashlib
import re
from dataclasses import dataclass, field
from pathlib import Path

from cnep.runtime.constants import FORMAT_VERSION, MANIFEST_FILE, MANIFEST_FORMAT, READ_VERSIONS, RUNTIME_FOLDER
from cnep.runtime.errors import PolicyError
from cnep.runtime.jsonfile import read_json
from cnep.runtime.spec import PolicySpec

HASH_BLOCK = 1 << 20  # bytes read at a time when hashing a file
# A plain file name: no separator, not `.` or `..`, no drive, not hidden; what `cnep export` names its files.
PLAIN_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9._-]*")


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
        if version not in READ_VERSIONS or isinstance(version, bool):
            raise PolicyError(
                f"{path}: policy format_version {version!r} is not supported by this runtime (supports "
                f"{', '.join(map(str, READ_VERSIONS))}); export the checkpoint again with this cnep-pipeline, or "
                f"install the runtime that came with the export (pip install {path.parent}/runtime)"
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
        except (KeyError, TypeError, ValueError, AttributeError, OverflowError) as exc:
            raise PolicyError(f"{path}: the manifest lacks or mangles {exc}; export the checkpoint again") from None

    def check_names(self, path: Path) -> None:
        """PolicyError (naming the manifest at `path`) unless every file it names is inside its folder: the graphs
        and the listed files plain names, the runtime's source a relative path of plain names under `runtime/`."""
        missing = [key for key in ("encoder", "decoder") if key not in self.graphs]
        if missing:
            raise PolicyError(f"{path}: graphs lacks {missing[0]!r}; export the checkpoint again")
        graphs = [("graphs", name) for name in self.graphs.values()]
        graphs += [
            ("features", entry.get("file") if isinstance(entry, dict) else entry) for entry in self.features.values()
        ]
        for entry, name in [*graphs, *(("files", name) for name in self.files)]:
            source = entry == "files" and isinstance(name, str) and name.startswith(RUNTIME_FOLDER + "/")
            parts = name[len(RUNTIME_FOLDER) + 1 :].split("/") if source else [name]
            if not all(isinstance(part, str) and PLAIN_NAME.fullmatch(part) for part in parts):
                raise PolicyError(
                    f"{path}: {entry} names {name!r}, which is not a plain file name inside the folder (a policy "
                    f"folder never points outside itself); export the checkpoint again"
                )
            if entry != "files" and name not in self.files:
                raise PolicyError(f"{path}: lists no hash for {name}; export the checkpoint again")

    def verified(self, folder: Path, name: str) -> Path:
        """The path of file `name` in `folder`, after checking it against the manifest's sha256."""
        path = folder / name
        expected = self.files.get(name)
        if expected is None:
            raise PolicyError(f"{folder / MANIFEST_FILE}: lists no hash for {name}; export the checkpoint again")
        if path.is_symlink():
            raise PolicyError(f"{path}: is a link; a policy folder holds its own files: export the checkpoint again")
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
    """The manifest of the exported policy in `folder`, every file it names checked to be inside the folder."""
    folder = Path(folder)
    path = folder / MANIFEST_FILE
    if not path.is_file():
        hint = (
            " (this is a checkpoint folder: export it with `cnep export`)" if (folder / "config.json").is_file() else ""
        )
        raise PolicyError(f"{folder}: no {MANIFEST_FILE} here{hint}; give a folder written by `cnep export`")
    if path.is_symlink():
        raise PolicyError(f"{path}: is a link; a policy folder holds its own files: export the checkpoint again")
    try:
        data = read_json(path)
    except (OSError, ValueError) as exc:
        raise PolicyError(f"{path}: cannot read the manifest ({exc}); export the checkpoint again") from None
    manifest = Manifest.from_dict(data, path)
    manifest.check_names(path)
    return manifest


def check_closed(folder: Path, manifest: Manifest) -> None:
    """PolicyError naming the first entry of `folder` that is neither the manifest, a file it lists (a plain file,
    not a link) nor the `runtime/` folder (the runtime's source: pip installs it, the loader never reads it)."""
    listed = {name for name in manifest.files if "/" not in name}
    for entry in sorted(folder.iterdir()):
        if entry.name == RUNTIME_FOLDER and entry.is_dir() and not entry.is_symlink():
            continue
        if entry.name in listed | {MANIFEST_FILE} and entry.is_file() and not entry.is_symlink():
            continue
        what = "a link" if entry.is_symlink() else "a folder" if entry.is_dir() else "a file"
        raise PolicyError(
            f"{entry}: {what} that {MANIFEST_FILE} does not list; a policy folder holds only what `cnep export` "
            f"wrote, so this one is refused: remove it, or export the checkpoint again"
        )


def file_sha256(path: str | Path) -> str:
    """sha256 of the file's bytes (hex)."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(HASH_BLOCK):
            digest.update(block)
    return digest.hexdigest()
