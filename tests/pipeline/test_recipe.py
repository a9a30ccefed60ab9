"""Every setting of the training recipe (the model's, the training's with its schedule, the conditioning's) given to
`cnep train` reaches config.json, the exported manifest and every runtime Policy made of the model. The settings are
walked from the configs' fields, so a setting added to one of them is checked with no edit here."""

import json
from pathlib import Path

import pytest

from cnep.models import read_checkpoint_config
from cnep.models.schedule import ONLINE_SHARE
from cnep.pipeline.cli.fields import Option
from cnep.pipeline.cli.main import main
from cnep.pipeline.cli.train import settings_of
from cnep.pipeline.export.policy import checkpoint_policy
from cnep.runtime import load_policy, read_manifest

pytestmark = pytest.mark.usefixtures("one_thread")

RECIPE = {"model": "model", "training": "training", "conditioning": "conditioning"}  # option group -> config.json key
SMALL = {"steps": 2, "batch_size": 4}  # a setting's other value where its default would train too long


def other_value(option: Option) -> object:
    """A value of `option` other than its default, small enough to train in a moment."""
    if option.name in SMALL:
        return SMALL[option.name]
    choices, default = option.field.metadata.get("choices"), option.default
    if choices:
        return next(choice for choice in choices if choice != default)
    if option.kind is tuple:
        return tuple(max(1, width // 16) for width in default)
    if option.kind is float:
        return default / 2 if default else 0.25
    return 2 if default is None else default + 1


def recipe_options() -> list[Option]:
    return [option for option in settings_of().values() if option.group in RECIPE]


def flag_words(option: Option, value: object) -> list[str]:
    return [option.flag, ",".join(map(str, value)) if isinstance(value, tuple) else str(value)]


@pytest.fixture(scope="module")
def trained(tmp_path_factory, policy_world) -> tuple[Path, dict[str, dict]]:
    """A checkpoint of the demo's trajectories (image features beside the motion, so that every setting applies)
    trained with every recipe setting away from its default; config.json key -> the settings given (field name ->
    value as JSON holds it)."""
    root = tmp_path_factory.mktemp("recipe")
    data = policy_world.checkpoint.parents[1] / "trajectories" / "train"
    chosen = {option: other_value(option) for option in recipe_options()}
    argv = ["-q", "train", str(data), "--out", str(root / "ckpt")]
    assert main(argv + [word for option, value in chosen.items() for word in flag_words(option, value)]) == 0
    given: dict[str, dict] = {key: {} for key in RECIPE.values()}
    for option, value in chosen.items():
        given[RECIPE[option.group]][option.field.name] = json.loads(json.dumps(value))
    return root / "ckpt", given


def test_the_recipe_walks_the_model_training_and_conditioning_settings():
    groups = {option.group for option in recipe_options()}
    assert groups == set(RECIPE)
    names = {option.field.name for option in recipe_options()}
    assert {"assignment", "nll_beta", "steps", "warmup_steps", "val_every", "patience", "window"} <= names


def test_every_recipe_setting_reaches_config_json_the_manifest_and_the_policies(trained, policy_world, tmp_path):
    checkpoint, given = trained
    config = read_checkpoint_config(checkpoint)
    extractor = str(policy_world.extractor)
    assert main(["-q", "export", str(checkpoint), "--out", str(tmp_path / "policy"), "--extractor", extractor]) == 0
    spec = read_manifest(tmp_path / "policy").spec
    policies = (load_policy(tmp_path / "policy", threads=1), checkpoint_policy(checkpoint, extractor, threads=1))
    for key, settings in given.items():
        for name, value in settings.items():
            assert config[key][name] == value, (key, name)
            if key == "conditioning":
                carried = [spec.conditioning.to_dict()] + [p.spec.conditioning.to_dict() for p in policies]
            else:
                carried = [spec.recipe[key]] + [p.spec.recipe[key] for p in policies]
            assert all(entry[name] == value for entry in carried), (key, name)
    schedule = config["training"]["schedule"]
    assert set(schedule["given"]) == {"steps", "warmup_steps", "val_every", "feature_components", "online_contexts"}
    assert spec.recipe["training"]["schedule"]


def test_a_camera_model_trains_on_its_policys_contexts_and_a_motion_model_on_the_papers(policy_world, motion_world):
    for checkpoint, share in ((policy_world.checkpoint, ONLINE_SHARE), (motion_world.ckpt, 0.0)):
        training = read_checkpoint_config(checkpoint)["training"]
        assert training["online_contexts"] == training["schedule"]["online_contexts"] == share, checkpoint
        assert "online_contexts" not in training["schedule"]["given"]
