"""The install maps the four root folders into one `cnep` namespace, and a user's own packages never shadow it."""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FOLDERS = ("models", "perception", "pipeline", "recordings")


def test_every_package_folder_is_installed_under_cnep():
    tomllib = pytest.importorskip("tomllib")
    settings = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert settings["package-dir"] == {f"cnep.{f}": f for f in FOLDERS}
    on_disk = {
        "cnep." + ".".join(p.parent.relative_to(ROOT).parts) for f in FOLDERS for p in (ROOT / f).rglob("__init__.py")
    }
    assert set(settings["packages"]) == on_disk


def test_a_users_own_models_and_pipeline_packages_do_not_shadow_the_library(tmp_path):
    for name in ("models", "pipeline", "recordings", "perception"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "__init__.py").write_text(f"raise SystemExit('the user\\'s {name} was imported')\n")
    code = (
        "import cnep.models, cnep.pipeline, cnep.recordings, cnep.perception\n"
        "from cnep.models import CNEPConfig\n"
        "print(cnep.models.__file__)"
    )
    done = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert Path(done.stdout.strip()).resolve() == ROOT / "models" / "__init__.py"
