"""The demo's measures on tiny models: the first-step prediction and how a generated path reads."""

import numpy as np
import pytest

from cnep.models import CNEP
from cnep.pipeline.demo.measures import first_step_prediction, nearest_behaviour
from cnep.pipeline.errors import PipelineError
from tests.models.factories import tiny_config


def test_a_model_without_query_columns_predicts_from_the_first_row_alone():
    model = CNEP(tiny_config(query_dim=0)).eval()
    rows = np.random.default_rng(0).random((12, model.config.columns.width), dtype=np.float32)  # (T, width)
    whole, first = first_step_prediction(model, rows), first_step_prediction(model, rows[:1], steps=12)
    assert first.mean.shape == whole.mean.shape == (12, model.config.columns.out_dim)
    np.testing.assert_array_equal(first.mean, whole.mean)
    np.testing.assert_array_equal(first.gate, whole.gate)
    with_queries = CNEP(tiny_config()).eval()  # its queries carry a column of every step
    with pytest.raises(PipelineError, match="give all 12 rows"):
        first_step_prediction(with_queries, rows[:1, : with_queries.config.columns.width], steps=12)


def test_a_path_reads_as_the_behaviour_of_the_nearest_training_path_of_its_length():
    t = np.linspace(0, 1, 10)[:, None]
    left, right = t * [-1.0, 0.0, 0.0], t * [1.0, 0.0, 0.0]  # (10, 3) each
    longer = np.linspace(0, 1, 12)[:, None] * [0.9, 0.0, 0.0]  # nearer, but of another length: never compared
    paths, labels = [left, right, longer], ["left", "right", "other"]
    assert nearest_behaviour(0.8 * right, paths, labels) == "right"
    assert nearest_behaviour(0.8 * left + 0.01, paths, labels) == "left"
