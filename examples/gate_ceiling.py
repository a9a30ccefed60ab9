"""How well can CNEP's encoder and gate name the modes of the 4-mode paper queries when told the modes?

    python examples/gate_ceiling.py [--seeds 3] [--steps 3000] [--set multimodal]

For each seed: the data set and paper queries of `cnep evaluate` (pipeline.evaluate.jobs.queries).
Four classifiers learn the demonstrations' mode labels (cross-entropy, Adam, batch 64) from contexts
shaped like the queries: one random interior step of a training demonstration and its end point.
    mean + linear  CNEP's encoder, masked mean, linear gate: the model's own gate, here supervised
    mean + MLP     the same, with a hidden layer of 256 in the gate
    concat + MLP   the same encoder; the two encodings concatenated, then a hidden layer of 256
    flat MLP       [time features, y at that time, y at the end] into an MLP 256 x 256
All four see the same inputs (time features and normalisation of models.CNEP). Prints each one's mode
accuracy on the paper queries. The unsupervised CNEP picks modes no better than its gate does here,
when the gate is given the labels (docs/concepts.md, "Commitment").
"""

from __future__ import annotations

import argparse

import numpy as np
import torch
from torch import nn

from cnep.models import CNEP, CNEPConfig
from cnep.models.cnep import mlp
from cnep.pipeline.evaluate.jobs import queries

BATCH = 64
HIDDEN = 256
EDGE = 10  # interior steps only, like the queries' intermediate points


class MeanLinear(nn.Module):
    def __init__(self, cnep: CNEP) -> None:
        super().__init__()
        self.cnep = cnep

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.cnep.gate(self.cnep.encode(obs, torch.ones(obs.shape[:2], dtype=torch.bool)))


class MeanMLP(nn.Module):
    def __init__(self, cnep: CNEP) -> None:
        super().__init__()
        self.cnep = cnep
        self.head = mlp([cnep.config.latent_dim, HIDDEN, cnep.n_experts])

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.head(self.cnep.encode(obs, torch.ones(obs.shape[:2], dtype=torch.bool)))


class ConcatMLP(nn.Module):
    def __init__(self, cnep: CNEP) -> None:
        super().__init__()
        self.cnep = cnep
        self.head = mlp([2 * cnep.config.latent_dim, HIDDEN, cnep.n_experts])

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.head(self.cnep.encoder(self.cnep.embed_time(obs)).flatten(1))


class Flat(nn.Module):
    def __init__(self, cnep: CNEP) -> None:
        super().__init__()
        self.cnep = cnep
        self.net = mlp([cnep.embed_time(torch.zeros(1, 2)).shape[-1] + 1, HIDDEN, HIDDEN, cnep.n_experts])

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.net(torch.cat([self.cnep.embed_time(obs[:, 0]), obs[:, 1, 1:]], dim=-1))


def contexts(cnep: CNEP, demos: torch.Tensor, rows: torch.Tensor, steps: torch.Tensor) -> torch.Tensor:
    """(B,) demonstrations and interior steps -> (B, 2, 2): [t, y] at the step and at the end, normalised."""
    T = demos.shape[1]
    t = torch.stack([steps / (T - 1), torch.ones(len(steps))], dim=1)  # (B, 2)
    y = torch.stack([demos[rows, steps], demos[rows, -1]], dim=1)  # (B, 2, 1)
    return cnep.prepare(t, y, cnep.obs_columns)


def accuracy(classifier: nn.Module, cnep: CNEP, data, paper, steps: int, seed: int) -> float:
    demos = torch.as_tensor(data.train, dtype=torch.float32)  # (N, T, 1)
    labels = torch.as_tensor(data.train_modes)
    generator = torch.Generator().manual_seed(seed)
    optimiser = torch.optim.Adam(classifier.parameters(), lr=1e-3)
    for _ in range(steps):
        rows = torch.randint(len(demos), (BATCH,), generator=generator)
        at = torch.randint(EDGE, demos.shape[1] - EDGE, (BATCH,), generator=generator)
        loss = nn.functional.cross_entropy(classifier(contexts(cnep, demos, rows, at)), labels[rows])
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
    with torch.no_grad():
        obs = torch.stack(
            [
                cnep.prepare(
                    torch.as_tensor(q.obs_t, dtype=torch.float32),
                    torch.as_tensor(q.obs_y, dtype=torch.float32),
                    cnep.obs_columns,
                )
                for q in paper
            ]
        )  # (Q, 2, 2)
        named = classifier(obs).argmax(-1).numpy()
    return float(np.mean(named == np.array([q.mode for q in paper])))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--seeds", type=int, default=3, help="seeds 0..N-1, each with its own data and queries (default 3)"
    )
    parser.add_argument("--steps", type=int, default=3000, help="training steps per classifier (default 3000)")
    parser.add_argument("--set", default="multimodal", help="synthetic set (default multimodal: 4 modes)")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    kinds = {"mean + linear": MeanLinear, "mean + MLP": MeanMLP, "concat + MLP": ConcatMLP, "flat MLP": Flat}
    results: dict[str, list[float]] = {name: [] for name in kinds}
    for seed in range(args.seeds):
        data, qs = queries(args.set, seed, 50)
        for name, kind in kinds.items():
            torch.manual_seed(seed)
            cnep = CNEP(CNEPConfig(n_experts=data.n_modes, assignment="paper"))
            cnep.normaliser.fit(list(data.train))
            results[name].append(accuracy(kind(cnep), cnep, data, qs["paper"], args.steps, seed))
            print(f"seed {seed} {name:14s} mode accuracy {results[name][-1]:.2f}", flush=True)
    for name, values in results.items():
        print(f"{name:14s} mean {np.mean(values):.3f} ({' '.join(f'{v:.2f}' for v in values)})")


if __name__ == "__main__":
    main()
