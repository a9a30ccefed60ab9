"""An exported folder is closed: the manifest names only plain files inside it, and it holds nothing else."""

import hashlib
import json
from pathlib import Path

import pytest

from cnep.runtime import PolicyError, read_manifest
from cnep.runtime.constants import DECODER_FILE, ENCODER_FILE, FEATURES_FILES, MANIFEST_FILE, MANIFEST_FORMAT
from cnep.runtime.manifest import check_closed
from tests.runtime.fakes import camera_spec

GRAPHS = {"encoder": ENCODER_FILE, "decoder": DECODER_FILE}
RUNTIME_FILE = "runtime/cnep/runtime/policy.py"
LISTED = {ENCODER_FILE: b"encoder", DECODER_FILE: b"decoder", FEATURES_FILES["fp32"]: b"features"}


def sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def write_folder(folder: Path, **changes) -> Path:
    """A policy folder of placeholder graphs (not ONNX: nothing here may reach a graph runner) and its manifest,
    with `changes` made to the manifest's entries."""
    files = LISTED
    (folder / "runtime" / "cnep" / "runtime").mkdir(parents=True)
    for name, data in {**files, RUNTIME_FILE: b"# the runtime's source"}.items():
        (folder / name).write_bytes(data)
    manifest = {
        "format": MANIFEST_FORMAT,
        "format_version": 1,
        "producer": "test",
        "spec": camera_spec().to_dict(),
        "extractor": {},
        "features": {"fp32": {"file": FEATURES_FILES["fp32"], "identity": {}}},
        "graphs": GRAPHS,
        "checkpoint": {},
        "files": {name: sha256(data) for name, data in {**files, RUNTIME_FILE: b"# the runtime's source"}.items()},
    }
    (folder / MANIFEST_FILE).write_text(json.dumps({**manifest, **changes}))
    return folder


def test_a_folder_as_exported_reads(tmp_path):
    manifest = read_manifest(write_folder(tmp_path))
    check_closed(tmp_path, manifest)
    assert manifest.graphs == GRAPHS and RUNTIME_FILE in manifest.files


@pytest.mark.parametrize(
    "name",
    ["../../../../../../etc/passwd", "../outside_encoder.onnx", "/etc/passwd", "sub/encoder.onnx", "..", ".hidden"],
)
def test_a_graph_named_outside_the_folder_is_refused_before_anything_is_opened(tmp_path, name):
    target = Path("/etc/passwd") if name.endswith("passwd") else tmp_path / "outside_encoder.onnx"
    if not target.exists():
        target.write_bytes(b"a graph outside the folder")
    folder = tmp_path / "policy"
    folder.mkdir()
    files = {name: sha256(target.read_bytes()), FEATURES_FILES["fp32"]: sha256(b"features")}
    write_folder(folder, graphs={"encoder": name, "decoder": DECODER_FILE}, files=files)
    with pytest.raises(PolicyError, match=r"manifest.json: graphs names .* not a plain file name inside the folder"):
        read_manifest(folder)


def test_a_listed_path_outside_the_folder_or_its_runtime_source_is_refused(tmp_path):
    for name in ("../notes.txt", "runtime/../../x.py", "/tmp/x.py", "runtime/", "other/x.py"):
        folder = tmp_path / str(abs(hash(name)))
        folder.mkdir()
        listed = {name: sha256(data) for name, data in LISTED.items()}
        write_folder(folder, files={**listed, name: "0"})
        with pytest.raises(PolicyError, match="files names .* not a plain file name inside the folder"):
            read_manifest(folder)


def test_a_feature_graph_outside_the_folder_is_refused(tmp_path):
    write_folder(tmp_path, features={"fp32": {"file": "/etc/passwd", "identity": {}}})
    with pytest.raises(PolicyError, match="features names '/etc/passwd'"):
        read_manifest(tmp_path)


def test_an_extra_python_file_is_refused_and_so_is_any_unlisted_entry(tmp_path):
    for extra in ("sitecustomize.py", "onnxruntime", "notes.txt"):
        folder = write_folder(tmp_path / extra)
        (folder / extra).write_text("import os\n")
        with pytest.raises(PolicyError, match=f"{extra}: a file that manifest.json does not list.*refused"):
            check_closed(folder, read_manifest(folder))
    folder = write_folder(tmp_path / "with_folder")
    (folder / "plugins").mkdir()
    with pytest.raises(PolicyError, match="plugins: a folder that manifest.json does not list"):
        check_closed(folder, read_manifest(folder))


def test_a_listed_graph_that_is_a_link_out_of_the_folder_is_refused(tmp_path):
    outside = tmp_path / "outside_encoder.onnx"
    outside.write_bytes(b"encoder")  # the same bytes, so the same sha256 as the manifest's
    folder = write_folder(tmp_path / "policy")
    (folder / ENCODER_FILE).unlink()
    (folder / ENCODER_FILE).symlink_to(outside)
    with pytest.raises(PolicyError, match="encoder.onnx: a link that manifest.json does not list"):
        check_closed(folder, read_manifest(folder))


def test_the_runtime_source_folder_is_not_read_so_what_pip_builds_there_is_ignored(tmp_path):
    folder = write_folder(tmp_path)
    build = folder / "runtime" / "build" / "lib" / "cnep" / "runtime"  # what `pip install DIR/runtime` leaves
    build.mkdir(parents=True)
    (build / "policy.py").write_text("# built\n")
    (folder / "runtime" / "cnep_runtime.egg-info").mkdir()
    check_closed(folder, read_manifest(folder))


def test_a_manifest_nested_thousands_of_levels_deep_is_refused_in_one_line(tmp_path):
    write_folder(tmp_path)
    (tmp_path / MANIFEST_FILE).write_text("[" * 5000 + "]" * 5000)
    with pytest.raises(PolicyError, match="cannot read the manifest \\(nested 5000 levels deep, deeper than the 64"):
        read_manifest(tmp_path)
