import pytest
import torch
from torchvision.models import mobilenet_v2

from cnep.perception import PerceptionError, find_imagenet_weights, resolve_weights, state_dict_sha256
from cnep.perception.constants import IMAGENET_WEIGHT_FILES, WEIGHTS_ENV_VAR
from cnep.perception.weights import save_state_dict


@pytest.fixture
def empty_hub(tmp_path, monkeypatch):
    """A torch hub cache with no weights in it and no environment override."""
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch"))
    monkeypatch.delenv(WEIGHTS_ENV_VAR, raising=False)
    return tmp_path / "torch" / "hub" / "checkpoints"


def _full_model_state_dict(seed: int) -> dict:
    torch.manual_seed(seed)
    return mobilenet_v2(weights=None).state_dict()  # keys features.* and classifier.*


def test_random_weights_are_seeded():
    a, b, c = resolve_weights("random", seed=0), resolve_weights("random", seed=0), resolve_weights("random", seed=1)
    assert a.name == "random:seed=0" and a.is_random
    assert state_dict_sha256(a.state_dict) == state_dict_sha256(b.state_dict)
    assert state_dict_sha256(a.state_dict) != state_dict_sha256(c.state_dict)


def test_random_weights_leave_the_global_rng_alone():
    torch.manual_seed(5)
    expected = torch.rand(3)
    torch.manual_seed(5)
    resolve_weights("random", seed=0)
    assert torch.equal(torch.rand(3), expected)


def test_path_loader_round_trips_a_full_torchvision_state_dict(tmp_path):
    full = _full_model_state_dict(seed=3)
    torch.save(full, tmp_path / "mine.pth")
    weights = resolve_weights(tmp_path / "mine.pth")
    assert weights.name == "path:mine.pth" and not weights.is_random
    features = {k[len("features.") :]: v for k, v in full.items() if k.startswith("features.")}
    assert state_dict_sha256(weights.state_dict) == state_dict_sha256(features)


def test_saved_features_load_back_identically(tmp_path):
    original = resolve_weights("random", seed=7).state_dict
    save_state_dict(original, tmp_path / "calibrated.pt")
    loaded = resolve_weights(str(tmp_path / "calibrated.pt")).state_dict
    assert state_dict_sha256(loaded) == state_dict_sha256(original)
    assert list(tmp_path.iterdir()) == [tmp_path / "calibrated.pt"]  # no temporary file left behind


def test_safetensors_file_loads(tmp_path):
    from safetensors.torch import save_file

    full = _full_model_state_dict(seed=4)
    save_file({k: v.contiguous() for k, v in full.items()}, str(tmp_path / "w.safetensors"))
    features = {k[len("features.") :]: v for k, v in full.items() if k.startswith("features.")}
    assert state_dict_sha256(resolve_weights(tmp_path / "w.safetensors").state_dict) == state_dict_sha256(features)


def test_imagenet_found_in_the_hub_cache(empty_hub):
    empty_hub.mkdir(parents=True)
    name = "mobilenet_v2-7ebf99e0.pth"
    torch.save(_full_model_state_dict(seed=1), empty_hub / name)
    assert find_imagenet_weights() == empty_hub / name
    assert resolve_weights("imagenet").name == f"imagenet:{name}"


def test_imagenet_from_the_environment_variable(empty_hub, tmp_path, monkeypatch):
    torch.save(_full_model_state_dict(seed=2), tmp_path / "elsewhere.pth")
    monkeypatch.setenv(WEIGHTS_ENV_VAR, str(tmp_path / "elsewhere.pth"))
    assert resolve_weights("imagenet").name == "imagenet:elsewhere.pth"


def test_missing_imagenet_weights_say_what_where_and_how(empty_hub):
    with pytest.raises(PerceptionError) as info:
        resolve_weights("imagenet")
    message = str(info.value)
    for name, url in IMAGENET_WEIGHT_FILES.items():
        assert name in message and url in message
    assert str(empty_hub) in message and WEIGHTS_ENV_VAR in message and "random" in message


def test_environment_variable_pointing_nowhere_is_named(empty_hub, tmp_path, monkeypatch):
    monkeypatch.setenv(WEIGHTS_ENV_VAR, str(tmp_path / "nope.pth"))
    with pytest.raises(PerceptionError, match=f"{WEIGHTS_ENV_VAR}=.*nope.pth is not a file"):
        resolve_weights("imagenet")


def test_missing_path_is_named(tmp_path):
    with pytest.raises(PerceptionError, match="absent.pth does not exist"):
        resolve_weights(tmp_path / "absent.pth")


def test_garbage_file_is_not_loaded(tmp_path):
    (tmp_path / "bad.pth").write_bytes(b"definitely not a checkpoint")
    with pytest.raises(PerceptionError, match="cannot load weights file .*bad.pth"):
        resolve_weights(tmp_path / "bad.pth")


def test_a_pickled_module_is_refused_by_weights_only(tmp_path):
    torch.save(mobilenet_v2(weights=None), tmp_path / "module.pth")  # a whole pickled model, not a state dict
    with pytest.raises(PerceptionError, match="cannot load weights file"):
        resolve_weights(tmp_path / "module.pth")


def test_other_architecture_is_refused(tmp_path):
    torch.save(torch.nn.Linear(3, 2).state_dict(), tmp_path / "linear.pth")
    with pytest.raises(PerceptionError, match="not a MobileNet-v2 state dict"):
        resolve_weights(tmp_path / "linear.pth")


def test_wrong_shape_is_named(tmp_path):
    full = _full_model_state_dict(seed=0)
    full["features.0.0.weight"] = torch.zeros(16, 3, 3, 3)
    torch.save(full, tmp_path / "narrow.pth")
    with pytest.raises(PerceptionError, match=r"features.0.0.weight has shape \(16, 3, 3, 3\)"):
        resolve_weights(tmp_path / "narrow.pth")
