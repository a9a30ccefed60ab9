"""Stage `export`: a checkpoint folder -> a policy folder that runs without torch (cnep.runtime).

    export(ExportConfig(checkpoint=Path("checkpoints/cnep"), out=Path("policy"), extractor=Path("extractor.pt")))

OUT gets
    manifest.json          runtime.manifest: the spec, the extractor identities, every file's sha256
    features.onnx          the feature network, uint8 pixels -> features (fp32), if the model sees the camera
    features-int8.onnx     its int8 quantisation (with `int8`, calibrated on the frames of `calibration`)
    encoder.onnx           the model's encoder, any number of context points
    decoder.onnx           its gate and experts, any number of query times
    runtime/               the runtime's source with a pyproject.toml: `pip install OUT/runtime` installs
                           cnep.runtime with numpy, onnxruntime and opencv only

The graphs are checked against torch before anything is written; the run holds the lock on OUT
(cnep.outputs), assembles the folder under a temporary name beside it and renames it when complete
(`pipeline.folders`). An existing OUT is replaced only with `force`, and only if its manifest, the policy folder's
record, names every file in it unchanged (`in_manifest`), checked again at the moment it is replaced.
"""

from __future__ import annotations

import json
import logging
from dataclasses import replace
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import cnep.runtime
from cnep.models.checkpoint import CONFIG_FILE, config_checksum
from cnep.outputs import writing_as
from cnep.perception import FeatureExtractor
from cnep.perception.constants import CALIBRATION_FRAMES
from cnep.pipeline.contract import refuse_existing, refuse_inputs
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.export.config import ExportConfig
from cnep.pipeline.export.graphs import model_graphs
from cnep.pipeline.export.policy import LoadedCheckpoint, load_for_policy
from cnep.pipeline.extract.stage import calibration_frames
from cnep.pipeline.folders import assembled_folder
from cnep.pipeline.inputs import find_demonstration_files
from cnep.runtime.constants import (
    DECODER_FILE,
    ENCODER_FILE,
    FEATURES_FILES,
    MANIFEST_FILE,
    RUNTIME_FOLDER,
    RUNTIME_REQUIREMENTS,
)
from cnep.runtime.errors import PolicyError
from cnep.runtime.manifest import Manifest, file_sha256, read_manifest
from cnep.runtime.timebase import TimeBase

log = logging.getLogger(__name__)

EXPORT_BACKEND = "onnxruntime"  # the export checks its graphs on ONNX Runtime (the `onnx` extra)


def in_manifest(root: Path, path: Path) -> bool:
    """Whether `path`, in the policy folder `root`, is the folder's readable manifest or a file it names (the
    folder's record: every file with its sha256) unchanged."""
    try:
        listed = read_manifest(root).files
    except PolicyError:
        return False
    if path == root / MANIFEST_FILE:
        return True
    return not path.is_symlink() and listed.get(path.relative_to(root).as_posix()) == file_sha256(path)


@writing_as("export")
def export(config: ExportConfig) -> Path:
    """Write the exported policy folder `config.out` from `config.checkpoint`; returns `config.out`."""
    out = Path(config.out)
    calibration = find_demonstration_files(config.calibration)
    refuse_inputs([out], [Path(config.checkpoint), *calibration, *([config.extractor] if config.extractor else [])])

    def refuse() -> None:
        refuse_existing([out], config.force, "exported policy", owns=in_manifest)

    refuse()
    loaded = with_time_base(
        load_for_policy(config.checkpoint, config.extractor, backend=EXPORT_BACKEND, threads=1), config.time_base
    )
    loaded = replace(
        loaded, spec=replace(loaded.spec, conditioning=config.conditioning.applied(loaded.spec.conditioning))
    )
    with assembled_folder(out, refuse, in_manifest) as work:
        write_policy(work, loaded, config, calibration)
    log.info("exported %s -> %s", config.checkpoint, out)
    return out


def with_time_base(loaded: LoadedCheckpoint, time_base: TimeBase | None) -> LoadedCheckpoint:
    """`loaded` with `time_base` in its spec (None: the checkpoint's); PipelineError when neither gives one."""
    spec = replace(loaded.spec, time_base=time_base or loaded.spec.time_base)
    if spec.time_base is None:
        raise PipelineError(
            f"{loaded.trained.path / CONFIG_FILE}: the checkpoint carries no time base (its training demonstrations' "
            f"length and step period in seconds, which map a robot's clock onto the model's phase); give them with "
            f"--time-base DURATION_S,PERIOD_S"
        )
    return replace(loaded, spec=spec)


def write_policy(folder: Path, loaded: LoadedCheckpoint, config: ExportConfig, calibration: list[Path]) -> None:
    """The graphs, the runtime's source and the manifest (last, with every other file's sha256) into `folder`."""
    config_json = loaded.trained.config
    features = {}
    if loaded.extractor is not None:
        extractors = {"fp32": loaded.extractor}
        if config.int8:
            extractors["int8"] = int8_extractor(config, calibration)
        for precision, extractor in extractors.items():
            write(folder / FEATURES_FILES[precision], extractor.onnx_graph())
            features[precision] = {"file": FEATURES_FILES[precision], "identity": extractor.identity}
    encoder, decoder = model_graphs(loaded.trained.model)
    write(folder / ENCODER_FILE, encoder)
    write(folder / DECODER_FILE, decoder)
    write_runtime(folder / RUNTIME_FOLDER)
    files = {str(p.relative_to(folder)): file_sha256(p) for p in sorted(folder.rglob("*")) if p.is_file()}
    manifest = Manifest(
        spec=loaded.spec,
        graphs={"encoder": ENCODER_FILE, "decoder": DECODER_FILE},
        features=features,
        extractor=dict(config_json.get("extractor") or {}),
        checkpoint={
            "config_sha256": config_checksum(config_json),
            "preset": (config_json.get("layout") or {}).get("name", ""),
        },
        producer=f"cnep-pipeline {package_version()}",
        files=files,
    )
    write(folder / MANIFEST_FILE, json.dumps(manifest.to_dict(), indent=1).encode())


def write(path: Path, data: bytes) -> None:
    """A file of the work folder, which is renamed into place only when complete (so no file needs its own rename)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)


def int8_extractor(config: ExportConfig, calibration: list[Path]) -> FeatureExtractor:
    """The training features' extractor at precision int8, quantised on frames spread over `calibration`."""
    weights = "imagenet" if config.extractor is None else config.extractor
    extractor = FeatureExtractor(weights, backend=EXPORT_BACKEND, threads=1, precision="int8")
    extractor.quantise(calibration_frames(calibration, CALIBRATION_FRAMES))
    return extractor


def write_runtime(folder: Path) -> None:
    """cnep.runtime's source (the code this export was made with) and a pyproject.toml that installs it alone."""
    source = Path(cnep.runtime.__file__).parent
    for path in sorted(source.glob("*.py")):
        write(folder / "cnep" / "runtime" / path.name, path.read_bytes())
    write(folder / "pyproject.toml", runtime_pyproject(package_version()).encode())


def runtime_pyproject(release: str) -> str:
    """The pyproject.toml of the runtime alone: package cnep.runtime, its three requirements, no torch."""
    requirements = ", ".join(f'"{r}"' for r in RUNTIME_REQUIREMENTS)
    return (
        '[build-system]\nrequires = ["setuptools>=68"]\nbuild-backend = "setuptools.build_meta"\n\n'
        f'[project]\nname = "cnep-runtime"\nversion = "{release}"\n'
        'description = "The torch-free runtime of cnep-pipeline: run an exported CNEP policy"\n'
        f'requires-python = ">=3.10"\ndependencies = [{requirements}]\n\n'
        '[tool.setuptools]\npackages = ["cnep.runtime"]\n'
    )


def package_version() -> str:
    """The installed cnep-pipeline's version (the runtime package is released with the same one)."""
    try:
        return version("cnep-pipeline")
    except PackageNotFoundError:
        return "0.0.0"
