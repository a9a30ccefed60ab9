"""The install maps the seven root folders into one `cnep` namespace, and a user's own packages never shadow it."""

import importlib
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FOLDERS = ("models", "outputs", "perception", "pipeline", "recordings", "runtime", "sim")
STAGES = ("ingest", "to_lerobot", "extract", "train", "replay", "export", "run", "evaluate", "demo", "sim")
LIGHT = {
    "cnep.models": "cnep.models.config",
    "cnep.recordings": "cnep.recordings.constants",
}  # a package's light module


def test_every_package_folder_is_installed_under_cnep():
    tomllib = pytest.importorskip("tomllib")
    settings = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert settings["package-dir"] == {f"cnep.{f}": f for f in FOLDERS}
    on_disk = {
        "cnep." + ".".join(p.parent.relative_to(ROOT).parts) for f in FOLDERS for p in (ROOT / f).rglob("__init__.py")
    }
    assert set(settings["packages"]) == on_disk


@pytest.mark.slow
def test_a_users_own_models_and_pipeline_packages_do_not_shadow_the_library(tmp_path):
    for name in FOLDERS:
        (tmp_path / name).mkdir()
        (tmp_path / name / "__init__.py").write_text(f"raise SystemExit('the user\\'s {name} was imported')\n")
    code = (
        "import cnep.models, cnep.pipeline, cnep.recordings, cnep.perception, cnep.runtime\n"
        "from cnep.models import CNEPConfig\n"
        "print(cnep.models.__file__)"
    )
    done = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert Path(done.stdout.strip()).resolve() == ROOT / "models" / "__init__.py"


@pytest.mark.parametrize("package", [*LIGHT, *(f"cnep.pipeline.{stage}" for stage in STAGES)])
def test_every_public_name_of_a_package_resolves_and_unknown_names_are_attribute_errors(package):
    module = importlib.import_module(package)
    assert module.__all__ == sorted(module.__all__) and module.__all__
    for name in module.__all__:
        assert getattr(module, name) is not None, name
    with pytest.raises(AttributeError, match="no attribute 'nothing_here'"):
        module.nothing_here  # noqa: B018
    assert importlib.import_module(LIGHT.get(package, f"{package}.stage"))


def test_the_packages_settings_and_constants_import_without_torch():
    code = (
        "import sys\n"
        "import cnep.models.config, cnep.models.errors\n"
        "import cnep.pipeline.train.constants, cnep.pipeline.evaluate.constants\n"
        "from cnep.pipeline.replay import __all__\n"
        "print(sorted(m for m in ('torch', 'onnx', 'rerun') if m in sys.modules))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"


def test_the_installed_cnep_command_runs_the_cli_and_exits_with_its_status(tmp_path):
    """The `cnep` script the install puts beside the interpreter calls the CLI's `main` (tests/test_docs.py runs the
    pages' `cnep` lines through `main` in-process): its help names every stage, a refusal is exit 2 and one line."""
    cnep = Path(sys.executable).parent / "cnep"
    done = subprocess.run([cnep, "--help"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert all(f"    {stage.replace('_', '-')} " in done.stdout for stage in STAGES), done.stdout
    missing = tmp_path / "missing.mcap"
    done = subprocess.run([cnep, "inspect", missing], capture_output=True, text=True, timeout=120)
    assert (done.returncode, done.stderr) == (2, f"cnep inspect: error: {missing}: no such file\n")
