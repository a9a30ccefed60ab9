import pytest

from cnep.models import CNEP, CNEPConfig, ColumnRoles, ConfigError, matched_cnmp, parameter_count

# The train stage's presets as models.ColumnRoles (pipeline.train.presets resolves them the same way).
ROLES = {
    "synthetic": ColumnRoles(),
    "motion": ColumnRoles(width=8, observed=((0, 8),), predicted=((0, 8),)),
    "scene-1288": ColumnRoles(width=1288, observed=((0, 1288),), predicted=((1280, 1288),)),
    "wine-glass-1288": ColumnRoles(width=1288, observed=((0, 1288),), query=((0, 1280),), predicted=((1280, 1288),)),
}


@pytest.mark.parametrize("preset", ROLES, ids=str)
@pytest.mark.parametrize("n_experts", [2, 4])
def test_matched_cnmp_is_within_one_percent_of_the_cnep(preset, n_experts):
    cnep = CNEPConfig(columns=ROLES[preset], n_experts=n_experts)
    cnmp = matched_cnmp(cnep)
    assert cnmp.n_experts == 1 and cnmp.columns == cnep.columns and cnmp.encoder_widths == cnep.encoder_widths
    assert cnmp.a_batch == 0.0 and cnmp.a_ind == 0.0  # the CNMP's own loss weights, not the CNEP's
    ratio = parameter_count(cnmp) / parameter_count(cnep)
    assert 1.0 <= ratio < 1.01, ratio
    narrower = CNEPConfig(columns=cnep.columns, n_experts=1, expert_widths=tuple(w - 1 for w in cnmp.expert_widths))
    assert parameter_count(narrower) < parameter_count(cnep)  # the smallest width that reaches the count


def test_parameter_count_counts_the_built_network():
    config = CNEPConfig(n_experts=3, expert_widths=(32, 16))
    assert parameter_count(config) == sum(p.numel() for p in CNEP(config).parameters())


def test_matched_cnmp_needs_a_hidden_expert_layer():
    with pytest.raises(ConfigError, match="expert_widths"):
        matched_cnmp(CNEPConfig(expert_widths=()))


def test_an_encoder_reading_feature_components_has_k_inputs_for_the_features_and_its_cnmp_too():
    scene = CNEPConfig(columns=ROLES["scene-1288"])
    projected = CNEPConfig(columns=ROLES["scene-1288"], feature_components=32)
    width = projected.encoder_widths[0]
    assert parameter_count(scene) - parameter_count(projected) == (1280 - 32) * width
    assert matched_cnmp(projected).feature_components == 32
    assert 1.0 <= parameter_count(matched_cnmp(projected)) / parameter_count(projected) < 1.01
