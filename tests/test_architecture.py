"""The import rules of docs/architecture.md, read from the source (every import, also inside functions)."""

import ast
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LIBRARIES = ("models", "recordings", "perception")
STAGE_ORDER = ("ingest", "to_lerobot", "extract", "train", "replay", "export", "run", "evaluate", "demo", "sim", "cli")


def imports(package: str) -> list[tuple[Path, str]]:
    """(file, imported module) for every import statement under ROOT/package."""
    found = []
    for path in sorted((ROOT / package).rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.Import):
                found += [(path, alias.name) for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                found.append((path, node.module))
    return found


def top(module: str) -> str:
    """The project package a module belongs to (`cnep.models.train` -> `models`), else its top-level name."""
    parts = module.split(".")
    return parts[1] if parts[0] == "cnep" and len(parts) > 1 else parts[0]


def stage_of(path: Path) -> str | None:
    """The stage folder a pipeline file belongs to; None for the shared modules directly under pipeline/."""
    parts = path.relative_to(ROOT / "pipeline").parts
    return parts[0] if len(parts) > 1 else None


@pytest.mark.parametrize("package", LIBRARIES)
def test_libraries_import_neither_pipeline_nor_each_other(package):
    forbidden = {"pipeline", *LIBRARIES} - {package}
    bad = [f"{p.relative_to(ROOT)}: {m}" for p, m in imports(package) if top(m) in forbidden]
    assert not bad, bad


def test_outputs_imports_no_other_part_of_cnep_and_only_the_standard_library_and_filelock():
    project = {"pipeline", "outputs", *LIBRARIES}
    bad = [
        f"{p.relative_to(ROOT)}: {m}"
        for p, m in imports("outputs")
        if (m.startswith("cnep.") and top(m) in project - {"outputs"})
        or (not m.startswith("cnep.") and top(m) not in sys.stdlib_module_names | {"filelock"})
    ]
    assert not bad, bad


# What the runtime may import besides the standard library and itself: a robot installs it without torch.
RUNTIME_IMPORTS = {"numpy", "cv2", "onnxruntime", "openvino"}


def test_runtime_imports_only_numpy_opencv_onnx_runtimes_and_itself():
    allowed = RUNTIME_IMPORTS | set(sys.stdlib_module_names)
    bad = [
        f"{p.relative_to(ROOT)}: {m}"
        for p, m in imports("runtime")
        if not (m == "cnep.runtime" or m.startswith("cnep.runtime.") or m.split(".")[0] in allowed)
    ]
    assert not bad, bad


# The LeRobot plugin (integrations/): LeRobot and torch besides what the runtime and the simulator import, and of cnep
# those two alone, so that it installs beside LeRobot without the pipeline's dependencies; its adapter on numpy alone,
# so that the suite tests it where LeRobot is not installed.
PLUGIN = "integrations/lerobot_policy_cnep"
PLUGIN_IMPORTS = {"lerobot", "torch", "lerobot_policy_cnep", "numpy", "gymnasium"}


def test_the_lerobot_plugin_imports_only_lerobot_torch_and_cnep_runtime_and_sim():
    allowed = PLUGIN_IMPORTS | set(sys.stdlib_module_names)
    bad = [
        f"{p.relative_to(ROOT)}: {m}"
        for p, m in imports(PLUGIN)
        if not (top(m) in ("sim", "runtime") and m.startswith("cnep.") or m.split(".")[0] in allowed)
    ]
    assert not bad, bad
    adapter = [m for p, m in imports(PLUGIN) if p.name == "adapter.py"]
    assert {top(m) for m in adapter} <= {"numpy", "runtime", "__future__", "collections"}, adapter


# What the simulator may import besides the standard library and itself: its extra, numpy and the runtime it runs.
SIM_IMPORTS = {"numpy", "mujoco", "gymnasium"}


def test_sim_imports_only_numpy_mujoco_gymnasium_the_runtime_and_itself():
    allowed = SIM_IMPORTS | set(sys.stdlib_module_names)
    bad = [
        f"{p.relative_to(ROOT)}: {m}"
        for p, m in imports("sim")
        if not (top(m) in ("sim", "runtime") and m.startswith("cnep.") or m.split(".")[0] in allowed)
    ]
    assert not bad, bad


def test_recordings_never_imports_torch():
    bad = [f"{p.relative_to(ROOT)}: {m}" for p, m in imports("recordings") if top(m) == "torch"]
    assert not bad, bad


def test_every_pipeline_folder_is_a_known_stage():
    folders = {p.name for p in (ROOT / "pipeline").iterdir() if p.is_dir() and p.name != "__pycache__"}
    assert folders == set(STAGE_ORDER)


def test_stages_import_only_earlier_stages_and_shared_modules():
    bad = []
    for path, module in imports("pipeline"):
        parts = module.split(".")[1:] if module.startswith("cnep.") else []
        if not parts or parts[0] != "pipeline" or len(parts) < 2 or parts[1] not in STAGE_ORDER:
            continue
        importer, imported = stage_of(path), parts[1]
        if path.name == "__main__.py" and importer is None and imported == "cli":
            continue
        if importer is None or (importer != imported and STAGE_ORDER.index(imported) > STAGE_ORDER.index(importer)):
            bad.append(f"{path.relative_to(ROOT)}: {module}")
    assert not bad, bad
