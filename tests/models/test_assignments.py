import dataclasses

import pytest
import torch

from cnep.models.assignments import ASSIGNMENTS, POSTERIOR, Assignment, assignment_named
from cnep.models.config import CNEPConfig, TrainConfig
from cnep.models.errors import ConfigError
from cnep.models.loss import RECONSTRUCTIONS, reconstruction


def test_every_assignment_is_one_definition_that_the_config_the_trainer_and_the_loss_read():
    for name, assignment in ASSIGNMENTS.items():
        assert assignment.name == name and assignment.term in RECONSTRUCTIONS
        assert CNEPConfig(assignment=name).assigned is assignment
        assert TrainConfig().for_assignment(assignment).gate_lr_scale == assignment.gate_lr_scale
        assert TrainConfig(gate_lr_scale=0.5).for_assignment(assignment).gate_lr_scale == 0.5  # given: kept
        settles = assignment.balancing.until if assignment.balancing else 0.0
        assert assignment.settled_fraction == settles and assignment.uses_demonstration == (settles > 0)
    assert ASSIGNMENTS["paper"].balancing is None and ASSIGNMENTS["bounded"].balancing.floor == 0.75


def test_an_unknown_assignment_is_refused_naming_the_known_ones():
    with pytest.raises(ConfigError, match="paper, mixture, annealed, bounded.*'greedy'"):
        CNEPConfig(assignment="greedy")
    with pytest.raises(ConfigError, match="got 'greedy'"):
        assignment_named("greedy")


def test_a_new_assignment_is_one_definition(monkeypatch):
    """A fifth assignment: the bounded posterior with other bounds, defined once, reaches the config and the loss."""
    wide = dataclasses.replace(ASSIGNMENTS["bounded"].balancing, floor=0.5, cap=2.0)
    fifth = Assignment("wide", POSTERIOR, 0.5, "bounded within 0.5-2x", wide)
    monkeypatch.setitem(ASSIGNMENTS, "wide", fifth)
    assert CNEPConfig(assignment="wide").assigned is fifth
    g = torch.Generator().manual_seed(0)
    nll, gate = torch.rand(8, 2, generator=g), torch.softmax(torch.randn(8, 2, generator=g), -1)
    values = torch.full((8,), 4.0)
    own = reconstruction(nll, gate, values, fifth, progress=0.1)
    assert own != reconstruction(nll, gate, values, ASSIGNMENTS["bounded"], progress=0.1)  # its bounds act
    assert own == reconstruction(nll, gate, values, dataclasses.replace(ASSIGNMENTS["bounded"], balancing=wide), 0.1)
