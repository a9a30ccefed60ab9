"""What the commands say: option values that look like options, a --force suggested only where it would work, an
error line that stands alone after a progress bar, a refused pickle without torch's advice to unpickle it anyway,
a 16-bit image reduced once with a word."""

from __future__ import annotations

import logging
import os
import shutil

import cv2
import numpy as np
import pytest
import torch

from cnep.perception.errors import PerceptionError
from cnep.perception.weights import resolve_weights
from cnep.pipeline.cli.main import main
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.train.state import load_state
from cnep.recordings import media
from tests.pipeline.test_contract import TINY_TRAINING, assert_one_line, run_cli, world  # noqa: F401


class RunsCode:
    """A pickle that would call os.system when unpickled (weights_only refuses it)."""

    def __reduce__(self):
        return (os.system, ("echo never",))


@pytest.mark.parametrize("command", ["run", "export"])
def test_a_time_base_starting_with_a_minus_sign_is_read_as_the_value(world, tmp_path, capsys, command):  # noqa: F811
    argv = {
        "run": ["run", world.ckpt, world.demos / "d0.mcap", "--out", tmp_path / "r.rrd", "--fast"],
        "export": ["export", world.ckpt, "--out", tmp_path / "policy"],
    }[command]
    capsys.readouterr()
    with pytest.raises(SystemExit) as stopped:  # a bad option: argparse's usage line, then its error line
        main(["-q", *map(str, argv), "--time-base", "-1,0.05"])
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert stopped.value.code == 2 and line.startswith(f"cnep {command}: error: argument --time-base: ")
    assert "expected one argument" not in line and "got -1.0" in line  # the value's own problem
    assert not (tmp_path / "policy").exists() and not (tmp_path / "r.rrd").exists()


def test_force_is_suggested_only_where_it_would_replace_the_output(world, tmp_path, capsys):  # noqa: F811
    argv = ["train", world.trajs, "--out", tmp_path / "ckpt", *TINY_TRAINING]
    (tmp_path / "ckpt").write_text("my notes")  # a file of the user's: --force would refuse it
    code, err = run_cli(argv, capsys)
    line = assert_one_line(err, "train", str(tmp_path / "ckpt"), "--force would not replace it either")
    assert code == 2 and "add --force" not in line
    assert run_cli([*argv, "--force"], capsys)[0] == 2 and (tmp_path / "ckpt").read_text() == "my notes"
    (tmp_path / "ckpt").unlink()
    shutil.copytree(world.ckpt, tmp_path / "ckpt")  # a checkpoint cnep recorded writing: --force would replace it
    code, err = run_cli(argv, capsys)
    assert code == 2 and "add --force" in assert_one_line(err, "train", str(tmp_path / "ckpt"))
    assert run_cli([*argv, "--force"], capsys)[0] == 0


def test_an_error_line_is_not_preceded_by_a_progress_bar_line(world, tmp_path, capsys):  # noqa: F811
    """Without -q (stderr is not a terminal here: bars are whole lines), a stage that fails mid-bar prints no line of
    its bar, before or after the error."""
    src = tmp_path / "src"
    shutil.copytree(world.demos, src)
    (src / "d2.mcap").write_bytes((src / "d2.mcap").read_bytes()[:300])  # the last input is cut short
    capsys.readouterr()
    assert main(["extract", str(src), "--out", str(tmp_path / "out")]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines[-1].startswith("cnep extract: error: ") and str(src / "d2.mcap") in lines[-1], lines
    assert not any(line.startswith("extract:") for line in lines), lines  # the bar's lines start with its name


def test_a_refused_pickle_gives_no_advice_to_unpickle_it(tmp_path):
    torch.save({"w": RunsCode()}, tmp_path / "evil.pt")
    with pytest.raises(PerceptionError) as refused:
        resolve_weights(tmp_path / "evil.pt")
    said = str(refused.value)
    assert "pickled Python objects" in said and "cnep loads tensors only" in said
    assert "weights_only" not in said and "trusted source" not in said
    with pytest.raises(PipelineError) as refused:
        load_state(tmp_path / "evil.pt")
    said = str(refused.value)
    assert "pickled Python objects" in said and "weights_only" not in said and "trusted source" not in said


def test_a_16_bit_png_is_reduced_to_8_bits_and_said_once(caplog, monkeypatch):
    monkeypatch.setattr(media, "_said_16_bit", [])
    image = (np.arange(16 * 16 * 3).reshape(16, 16, 3) * 97 % 65536).astype(np.uint16)  # (H, W, 3) 16-bit
    ok, png = cv2.imencode(".png", image)
    assert ok and png.tobytes()[24] == 16  # the header says 16 bits
    with caplog.at_level(logging.WARNING, logger="cnep.recordings.media"):
        jpegs = [media.as_jpeg(png.tobytes(), f"frame_{i}.png") for i in range(3)]
    said = [r.getMessage() for r in caplog.records if "16-bit" in r.getMessage()]
    assert len(said) == 1 and said[0].startswith("frame_0.png: a 16-bit PNG image, reduced to 8 bits per channel")
    decoded = cv2.imdecode(np.frombuffer(jpegs[0], np.uint8), cv2.IMREAD_UNCHANGED)
    assert decoded.dtype == np.uint8 and decoded.shape == (16, 16, 3)
    caplog.clear()
    ok, png8 = cv2.imencode(".png", (image >> 8).astype(np.uint8))
    with caplog.at_level(logging.WARNING, logger="cnep.recordings.media"):
        monkeypatch.setattr(media, "_said_16_bit", [])
        media.as_jpeg(png8.tobytes(), "eight.png")
    assert not caplog.records  # an 8-bit PNG: nothing to say
