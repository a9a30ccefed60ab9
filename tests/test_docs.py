"""The documentation as a user meets it: every Python snippet of README and docs runs, every `bash` block of the
how-to guides runs as printed (on small inputs built here under the names the page uses), links resolve, the CLI
reference equals what the parsers generate, and no page narrates how the project was made.

A page's `python` blocks run in one namespace (mktestdocs), its `bash` blocks one command after the other,
stopping at the first that fails (as `bash -e -u` runs them): a `cnep` command through the CLI's `main` in this
process, which is what the installed `cnep` script calls (tests/test_packaging.py runs the script itself), every
other line by bash; both from a fresh folder where `cnep-demo/` is the quick demo (a `make demo` stand-in). Blocks
marked `console` or `text` are shown, not run (multi-machine torchrun, GPUs, viewers, full-length runs).
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from mktestdocs import check_md_file, grab_code_blocks

from cnep.pipeline.cli.main import main
from cnep.pipeline.cli.reference import render
from cnep.pipeline.run import stage as run_stage
from cnep.pipeline.sim import recipe

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
GENERATED = DOCS / "reference" / "cli.md"
RECIPE = DOCS / "reference" / "training-recipe.md"
PAGES = [ROOT / "README.md", *sorted(DOCS.rglob("*.md"))]
MAX_LINES = 400
# A line only bash runs: variables, pipes, redirections, lists, sub-shells, globs.
SHELL_SYNTAX = re.compile(r"[$|;&<>`(){}*?]")
# A page whose blocks hold more than one command a line (a here-document, a loop, a condition) runs as one bash script.
COMPOUND = re.compile(r"<<|^\s*(if|for|while|until|case|function)\b", flags=re.M)
# What a page must not say: numbered work items, sessions, links out of the repository.
HISTORY = re.compile(r"[Ss]essions? [0-9]+|\b([Ff]rom|[Ii]n|[Ss]ee) issue #?[0-9]+|\([Ii]ssue #?[0-9]+|\.\./shared/")


def runnable(page: Path, lang: str) -> bool:
    return bool(grab_code_blocks(page.read_text(), lang=lang))


def name(page: Path) -> str:
    return str(page.relative_to(ROOT))


# ---- inputs each how-to guide starts from, under the names it uses --------------------------------------------


def recordings_with_video_and_images(work: Path) -> None:
    """recordings/pick_0{1,2} (an MP4 and a pose CSV, seconds) and recordings/pick_03 (one PNG per CSV row)."""
    import cv2

    from tests.recordings.lerobot_sources import write_video

    rng = np.random.default_rng(0)
    for k, kind in enumerate(("video", "video", "images")):
        folder = work / "recordings" / f"pick_0{k + 1}"
        folder.mkdir(parents=True)
        frames = [rng.integers(0, 256, (32, 32, 3), dtype=np.uint8) for _ in range(10)]
        if kind == "video":
            write_video(folder / "video.mp4", frames, fps=10)
        else:
            for i, frame in enumerate(frames):
                cv2.imwrite(str(folder / f"frame_{i:03d}.png"), frame)
        rows = ["t,x,y,z,qx,qy,qz,qw,grip"]  # one row per frame, 10 Hz
        rows += [f"{i / 10:.2f},{0.4 + 0.01 * i:.3f},-0.12,0.3,0,0,0,1,0.08" for i in range(len(frames))]
        (folder / "poses.csv").write_text("\n".join(rows) + "\n")


def lerobot_dataset(work: Path) -> None:
    from tests.recordings.lerobot_sources import build_lerobot

    build_lerobot(work / "my_lerobot_dataset", "v3.0", episodes=3, steps=6, size=32)


def ros_bags(work: Path) -> None:
    from tests.recordings.rosbag_sources import write_ros1_bag, write_ros2_bag

    (work / "bags").mkdir()
    write_ros1_bag(work / "bags" / "run0.bag")
    write_ros2_bag(work / "bags" / "run1", storage="sqlite3")


def demonstration_folders(work: Path) -> None:
    from cnep.recordings import write_demonstration
    from tests.recordings.factories import demonstration_factory

    for folder, seeds in (("demos", (0, 1)), ("more_demos", (2,))):
        (work / folder).mkdir()
        for seed in seeds:
            demo = demonstration_factory(steps=6, seed=seed, episode_id=f"pick_{seed}", frame_size=32)
            write_demonstration(work / folder / f"pick_{seed}.mcap", demo)


def truncated_recording(work: Path) -> None:
    """recording.mcap: a trajectory file of several chunks whose writer died (the last 40% of its bytes lost)."""
    from cnep.recordings import write_trajectory
    from tests.recordings.factories import trajectory_factory

    path = write_trajectory(work / "recording.mcap", trajectory_factory(steps=700))
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * 0.6)])


def few_demo_recordings(work: Path) -> None:
    """cnep-demo/demos/train and cnep-demo/demos/heldout with two and one of the quick demo's recordings: the page
    extracts them three times over, and the others would only add frames."""
    demo = (work / "cnep-demo").resolve()
    (work / "cnep-demo").unlink()
    for split, count in (("train", 2), ("heldout", 1)):
        folder = work / "cnep-demo" / "demos" / split
        folder.mkdir(parents=True)
        for recording in sorted((demo / "demos" / split).glob("*.mcap"))[:count]:
            (folder / recording.name).symlink_to(recording)


INPUTS = {
    "docs/how-to/extract-features.md": few_demo_recordings,
    "docs/how-to/own-csv-and-video.md": recordings_with_video_and_images,
    "docs/how-to/lerobot-dataset.md": lerobot_dataset,
    "docs/how-to/ros-bag.md": ros_bags,
    "docs/how-to/cluster.md": demonstration_folders,
    "docs/how-to/repair-a-recording.md": truncated_recording,
}


@pytest.fixture(scope="session")
def imagenet_stand_in(tmp_path_factory) -> Path:
    """A MobileNet-v2 state dict of seeded random weights where the ImageNet file would be (none can be
    downloaded here): `cnep extract` with its default weights loads it through $CNEP_MOBILENET_WEIGHTS."""
    import torch
    from torchvision.models import mobilenet_v2

    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("weights") / "mobilenet_v2-b0353104.pth"
    torch.save(mobilenet_v2().state_dict(), path)
    return path


@pytest.fixture
def page_folder(tmp_path, monkeypatch, quick_demo, imagenet_stand_in, one_thread) -> Path:
    """A fresh folder to run a page in, with the demo's outputs at cnep-demo/ and `cnep` on PATH."""
    (tmp_path / "cnep-demo").symlink_to(quick_demo, target_is_directory=True)
    (tmp_path / "home").mkdir()
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("HOME", str(tmp_path / "home"))  # the rerun CLI writes analytics under HOME
    monkeypatch.setenv("CI", "1")
    monkeypatch.setenv("PATH", f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}")
    monkeypatch.setenv("CNEP_MOBILENET_WEIGHTS", str(imagenet_stand_in))
    # `cnep run` paces its steps at the recording's rate; that pacing is tests/pipeline/test_run.py's to check, and a
    # page's run need not wait out the recordings' seconds
    monkeypatch.setattr(run_stage, "wait_until", lambda deadline_s: None)
    return tmp_path


@pytest.mark.slow
@pytest.mark.parametrize("page", [p for p in PAGES if runnable(p, "bash") or runnable(p, "python")], ids=name)
def test_page_runs_as_printed(page, page_folder):
    if runnable(page, "bash"):
        if name(page) in INPUTS:  # other pages start from the demo's outputs
            INPUTS[name(page)](page_folder)
        run_commands(page)
    if runnable(page, "python"):
        check_md_file(page, memory=True, lang="python")


def run_commands(page: Path) -> None:
    """Run the page's `bash` blocks in the current folder, one command a line (a trailing backslash continues it)."""
    script = "\n".join(grab_code_blocks(page.read_text(), lang="bash"))
    if COMPOUND.search(script):
        check_md_file(page, memory=True, lang="bash")
        return
    for line in script.replace("\\\n", " ").splitlines():
        words = shlex.split(line, comments=True)
        if not words:
            continue
        if words[0] == "cnep" and not SHELL_SYNTAX.search(line):
            try:
                status = main(words[1:])
            except SystemExit as exit:  # a usage error
                status = exit.code
        else:
            status = subprocess.run(["bash", "-e", "-u", "-c", line]).returncode
        assert status == 0, f"{name(page)}: `{line}` exited with {status}"


def test_cli_reference_is_generated_from_the_parsers():
    assert GENERATED.read_text() == render(), (
        f"{GENERATED.relative_to(ROOT)} differs from the parsers; regenerate it with `make docs`"
    )


def test_the_training_recipe_page_is_generated_from_the_code():
    assert RECIPE.read_text() == recipe.render(), (
        f"{RECIPE.relative_to(ROOT)} differs from the code; regenerate it with `make docs`"
    )


@pytest.mark.parametrize("page", [p for p in PAGES if p != GENERATED], ids=name)
def test_page_is_short(page):
    lines = len(page.read_text().splitlines())
    assert lines <= MAX_LINES, f"{name(page)}: {lines} lines; split it (pages stay under {MAX_LINES} lines)"


@pytest.mark.parametrize("page", PAGES, ids=name)
def test_links_resolve(page):
    for target in re.findall(r"\]\(([^)\s]+)\)", page.read_text()):
        if re.match(r"[a-z]+:", target):
            continue  # a web address
        path, _, anchor = target.partition("#")
        linked = (page.parent / path).resolve() if path else page
        assert linked.exists(), f"{name(page)}: the link {target} points at nothing"
        assert ROOT in linked.parents, f"{name(page)}: the link {target} leaves the repository"
        if anchor and linked.suffix == ".md":
            assert anchor in headings(linked), f"{name(page)}: no heading #{anchor} in {name(linked)}"


def headings(page: Path) -> set[str]:
    """The anchors of a page's headings, as GitHub makes them: lower case, punctuation dropped, spaces to '-'."""
    titles = re.findall(r"^#+ (.+)$", page.read_text(), flags=re.M)
    return {re.sub(r"[^\w\- ]", "", title.strip().lower()).replace(" ", "-") for title in titles}


def test_nothing_narrates_the_making_of_the_project():
    found = []
    for path in source_files():
        for number, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
            if HISTORY.search(line):
                found.append(f"{path.relative_to(ROOT)}:{number}: {line.strip()}")
    assert not found, "development history in the tree (say it in the present tense, or drop it):\n" + "\n".join(found)


def source_files() -> list[Path]:
    """The repository's .md, .py and .toml files but CHANGELOG.md (no hidden folders, no build output)."""
    found = []
    for folder, subfolders, files in os.walk(ROOT):
        subfolders[:] = sorted(d for d in subfolders if not d.startswith(".") and d != "build")
        found += [
            Path(folder) / f for f in sorted(files) if f.endswith((".md", ".py", ".toml")) and f != "CHANGELOG.md"
        ]
    return found


@pytest.mark.parametrize("page", sorted(DOCS.glob("results*.md")), ids=name)
def test_results_page_tables_are_read_in_a_minute(page):
    """Each claim on a results page is a table of at most 6 columns; wider per-seed detail goes to a CSV."""
    widest = max(
        (line.strip().strip("|").count("|") + 1, number)
        for number, line in enumerate(page.read_text().splitlines(), 1)
        if line.startswith("|")
    )
    assert widest[0] <= 6, f"{name(page)}:{widest[1]}: a table of {widest[0]} columns (at most 6)"
