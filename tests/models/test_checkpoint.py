import json

import numpy as np
import pytest
import torch

from cnep.models.checkpoint import (
    CHECKSUM_KEY,
    CONFIG_FILE,
    WEIGHTS_FILE,
    config_checksum,
    load_checkpoint,
    read_checkpoint_config,
    save_checkpoint,
)
from cnep.models.errors import ConfigError
from cnep.models.train import build_model
from tests.models.factories import feature_config, feature_trajectories, random_inputs, tiny_config


@pytest.fixture
def model():
    rng = np.random.default_rng(0)
    trajs = [rng.normal(3.0, 2.0, (20, 5)).astype(np.float32) for _ in range(4)]
    return build_model(tiny_config(), trajs, seed=0).eval()


def test_save_then_load_gives_identical_outputs(model, tmp_path):
    save_checkpoint(model, tmp_path / "ckpt", extra={"note": "kept"})
    loaded = load_checkpoint(tmp_path / "ckpt")
    assert loaded.config == model.config
    for k, v in model.state_dict().items():
        torch.testing.assert_close(loaded.state_dict()[k], v, rtol=0, atol=0)  # normaliser included
    obs, mask, query = random_inputs(model.config)
    for a, b in zip(model(obs, mask, query), loaded(obs, mask, query)):
        torch.testing.assert_close(a, b, rtol=0, atol=0)
    assert json.loads((tmp_path / "ckpt" / CONFIG_FILE).read_text())["note"] == "kept"
    assert not list((tmp_path / "ckpt").glob("*.tmp"))  # no temporary files left behind


def test_missing_or_unknown_checkpoints_are_clear_errors(model, tmp_path):
    with pytest.raises(ConfigError, match="no checkpoint config"):
        load_checkpoint(tmp_path / "nothing")
    save_checkpoint(model, tmp_path / "ckpt")
    cfg_path = tmp_path / "ckpt" / CONFIG_FILE
    cfg = json.loads(cfg_path.read_text())
    cfg_path.write_text(json.dumps({**cfg, "format_version": 99}))
    with pytest.raises(ConfigError, match="format_version 99"):
        load_checkpoint(tmp_path / "ckpt")


def test_an_edited_config_is_refused_by_its_checksum(model, tmp_path):
    save_checkpoint(model, tmp_path / "ckpt", extra={"extractor": {"weights_sha256": "ab" * 32}})
    cfg_path = tmp_path / "ckpt" / CONFIG_FILE
    cfg = json.loads(cfg_path.read_text())
    cfg_path.write_text(json.dumps({**cfg, "extractor": {"weights_sha256": "0" * 64}}, indent=2))
    with pytest.raises(ConfigError, match="does not match its checksum"):
        read_checkpoint_config(tmp_path / "ckpt")
    cfg_path.write_text(json.dumps({k: v for k, v in cfg.items() if k != CHECKSUM_KEY}))
    with pytest.raises(ConfigError, match="has no checksum"):
        read_checkpoint_config(tmp_path / "ckpt")
    cfg_path.write_text(json.dumps(cfg))  # the same entries, laid out differently: still accepted
    assert read_checkpoint_config(tmp_path / "ckpt")["extractor"]["weights_sha256"] == "ab" * 32


def test_a_config_that_names_the_columns_layout_and_has_no_assignment_loads_as_the_paper_trained_it(model, tmp_path):
    save_checkpoint(model, tmp_path / "ckpt")
    cfg_path = tmp_path / "ckpt" / CONFIG_FILE
    cfg = json.loads(cfg_path.read_text())
    written = {k: v for k, v in cfg["model"].items() if k not in ("columns", "assignment")}
    cfg["model"] = {**written, "layout": cfg["model"]["columns"]}  # as such a checkpoint's config.json holds it
    cfg[CHECKSUM_KEY] = config_checksum(cfg)
    cfg_path.write_text(json.dumps(cfg))
    loaded = load_checkpoint(tmp_path / "ckpt")
    assert loaded.config.columns == model.config.columns and loaded.config.assignment == "paper"
    obs, mask, query = random_inputs(model.config)
    for a, b in zip(model(obs, mask, query), loaded(obs, mask, query)):
        torch.testing.assert_close(a, b, rtol=0, atol=0)


def test_weights_that_do_not_match_the_config_are_refused_in_one_line(model, tmp_path):
    save_checkpoint(model, tmp_path / "ckpt")
    cfg_path = tmp_path / "ckpt" / CONFIG_FILE
    cfg = json.loads(cfg_path.read_text())
    cfg["model"]["expert_widths"] = [32, 32]
    cfg[CHECKSUM_KEY] = config_checksum(cfg)  # a consistent config that does not describe these weights
    cfg_path.write_text(json.dumps(cfg))
    with pytest.raises(ConfigError, match="do not match") as refused:
        load_checkpoint(tmp_path / "ckpt")
    assert "\n" not in str(refused.value) and len(str(refused.value)) < 400
    (tmp_path / "ckpt" / WEIGHTS_FILE).write_bytes(b"not safetensors")
    with pytest.raises(ConfigError, match="cannot read the weights"):
        load_checkpoint(tmp_path / "ckpt")


def test_checkpoint_files_are_readable_by_others_as_the_umask_allows(model, tmp_path):
    import os
    import stat

    save_checkpoint(model, tmp_path / "ckpt")
    mask = os.umask(0o022)
    os.umask(mask)
    for name in (CONFIG_FILE, WEIGHTS_FILE):
        mode = stat.S_IMODE((tmp_path / "ckpt" / name).stat().st_mode)
        assert mode == 0o666 & ~mask


def test_a_models_feature_projection_is_saved_and_restored(tmp_path):
    model = build_model(feature_config(components=3), feature_trajectories(), seed=0).eval()
    save_checkpoint(model, tmp_path / "ckpt")
    assert json.loads((tmp_path / "ckpt" / CONFIG_FILE).read_text())["model"]["feature_components"] == 3
    loaded = load_checkpoint(tmp_path / "ckpt")
    assert loaded.feature_projection.abs().sum() > 0
    assert torch.equal(loaded.feature_projection, model.feature_projection)
    obs, mask, query = random_inputs(model.config)
    for a, b in zip(model(obs, mask, query), loaded(obs, mask, query)):
        torch.testing.assert_close(a, b, rtol=0, atol=0)
