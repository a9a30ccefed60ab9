"""Batched experts vs a Python loop over experts: one CNEP training step, same weights, same numbers.

Run on demand (one thread; do not run it next to other heavy work):
    python -m benchmarks.bench_experts [--experts 2 4 8] [--batch 32] [--repeats 20]

For each number of experts d, the real `models.CNEP` (all experts as one stacked matrix product) is
compared with a reference written here: the same network with one `nn.Sequential` per expert, run in
a Python loop, initialised from the CNEP's weights. Both take identical batches; the benchmark asserts
that their outputs, losses and gradients agree (allclose), then times a full training step (forward,
loss, backward, Adam step) of each and reports the speed ratio. The batched model must be faster at
every d.
"""

from __future__ import annotations

import argparse
import time

import torch
import torch.nn.functional as F
from torch import nn

from cnep.models import CNEP, CNEPConfig
from cnep.models.loss import cnep_loss
from cnep.models.sampler import TrajectoryStack, sample_batch
from cnep.models.synthetic import make_set

SYNTHETIC_SET = "multimodal"
TOLERANCE = {"rtol": 1e-4, "atol": 1e-5}


class LoopExperts(nn.Module):
    """The CNEP's experts as `d` separate MLPs on `[r, embedded query]`, evaluated one after another."""

    def __init__(self, model: CNEP) -> None:
        super().__init__()
        ex, d = model.experts, model.n_experts
        w0 = ex.first_b.numel() // d
        self.mlps = nn.ModuleList()
        for e in range(d):
            block = slice(e * w0, (e + 1) * w0)
            first = nn.Linear(ex.first_r.shape[0] + ex.first_q.shape[0], w0)
            first.weight.data = torch.cat([ex.first_r[:, block], ex.first_q[:, block]]).T.clone()
            first.bias.data = ex.first_b[block].clone()
            layers: list[nn.Module] = [first]
            for w, b in zip(ex.weights, ex.biases):
                layer = nn.Linear(w.shape[1], w.shape[2])
                layer.weight.data, layer.bias.data = w[e].T.clone(), b[e, 0].clone()
                layers += [nn.ReLU(), layer]
            self.mlps.append(nn.Sequential(*layers))

    def forward(self, r: torch.Tensor, query: torch.Tensor) -> torch.Tensor:
        """r (B, H), query (B, M, dq) -> (B, d, M, out)."""
        x = torch.cat([r.unsqueeze(1).expand(-1, query.shape[1], -1), query], dim=-1)  # (B, M, H + dq)
        return torch.stack([mlp(x) for mlp in self.mlps], dim=1)  # (B, d, M, out)


class LoopCNEP(nn.Module):
    """A CNEP whose experts run in a Python loop; encoder and gate are copies of the batched model's."""

    def __init__(self, model: CNEP) -> None:
        super().__init__()
        self.batched = model
        self.encoder = nn.Sequential(*list(_copy(model).encoder))
        self.gate = _copy(model).gate
        self.experts = LoopExperts(model)

    def forward(self, obs, obs_mask, query):
        ref, dy = self.batched, self.batched.config.columns.out_dim
        w = obs_mask.to(obs.dtype).unsqueeze(-1)  # (B, N, 1)
        r = (self.encoder(ref.embed_time(obs)) * w).sum(1) / w.sum(1).clamp_min(1.0)  # (B, H)
        gate = torch.softmax(self.gate(r), dim=-1)  # (B, d)
        mean, raw = self.experts(r, ref.embed_time(query)).split(dy, dim=-1)  # (B, d, M, dy) each
        return mean, ref.config.min_std + F.softplus(raw), gate


def _copy(model: CNEP) -> CNEP:
    clone = CNEP(model.config)
    clone.load_state_dict(model.state_dict())
    return clone


def step_fn(model: nn.Module, config: CNEPConfig, batches: list, params):
    """A closure running one training step per call, cycling through `batches`."""
    optimizer = torch.optim.Adam(params, lr=1e-4)
    counter = [0]

    def step():
        b = batches[counter[0] % len(batches)]
        counter[0] += 1
        mean, std, gate = model(b.obs, b.obs_mask, b.query)
        loss, _ = cnep_loss(mean, std, gate, b.target, b.target_mask, config)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()

    return step


def check_same_numbers(model: CNEP, loop: LoopCNEP, batch) -> None:
    """Outputs, loss and every expert gradient of the two implementations agree."""
    outs_a = model(batch.obs, batch.obs_mask, batch.query)
    outs_b = loop(batch.obs, batch.obs_mask, batch.query)
    for a, b in zip(outs_a, outs_b):
        torch.testing.assert_close(a, b, **TOLERANCE)
    loss_a, _ = cnep_loss(*outs_a, batch.target, batch.target_mask, model.config)
    loss_b, _ = cnep_loss(*outs_b, batch.target, batch.target_mask, model.config)
    torch.testing.assert_close(loss_a, loss_b, **TOLERANCE)
    model.zero_grad()
    loop.zero_grad()
    loss_a.backward()
    loss_b.backward()
    ex, d = model.experts, model.n_experts
    w0 = ex.first_b.numel() // d
    for e, mlp in enumerate(loop.experts.mlps):
        block = slice(e * w0, (e + 1) * w0)
        first = torch.cat([ex.first_r.grad[:, block], ex.first_q.grad[:, block]]).T
        torch.testing.assert_close(first, mlp[0].weight.grad, **TOLERANCE)
        torch.testing.assert_close(ex.first_b.grad[block], mlp[0].bias.grad, **TOLERANCE)
        for layer, w, b in zip(mlp[2::2], ex.weights, ex.biases):
            torch.testing.assert_close(w.grad[e].T, layer.weight.grad, **TOLERANCE)
            torch.testing.assert_close(b.grad[e, 0], layer.bias.grad, **TOLERANCE)
    torch.testing.assert_close(model.gate.weight.grad, loop.gate.weight.grad, **TOLERANCE)


def seconds_per_step(step, repeats: int) -> float:
    """Median time of `repeats` steps after 3 warm-up steps."""
    for _ in range(3):
        step()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        step()
        times.append(time.perf_counter() - start)
    return sorted(times)[len(times) // 2]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--experts", type=int, nargs="+", default=[2, 4, 8])
    parser.add_argument("--batch", type=int, default=32)
    parser.add_argument("--repeats", type=int, default=20)
    args = parser.parse_args()
    torch.set_num_threads(1)
    torch.manual_seed(0)
    data = make_set(SYNTHETIC_SET, 0)
    print(
        f"one training step (batch {args.batch}, n_max = m_max = 10, {SYNTHETIC_SET} set, 1 thread), "
        f"median of {args.repeats}"
    )
    print(f"{'d':>3} {'batched ms':>11} {'loop ms':>9} {'loop / batched':>15}")
    for d in args.experts:
        config = CNEPConfig(n_experts=d, assignment="paper")
        model = CNEP(config)
        with torch.no_grad():  # a non-uniform gate, so the gate weights matter to the check
            model.gate.weight.normal_(0, 0.1)
        model.normaliser.fit(list(data.train))
        loop = LoopCNEP(model)
        stack = TrajectoryStack(list(data.train), model)
        g = torch.Generator().manual_seed(d)
        batches = [sample_batch(stack, args.batch, 10, 10, g) for _ in range(8)]
        check_same_numbers(model, loop, batches[0])
        loop_params = [p for n, p in loop.named_parameters() if not n.startswith("batched.")]
        batched = seconds_per_step(step_fn(model, config, batches, model.parameters()), args.repeats)
        looped = seconds_per_step(step_fn(loop, config, batches, loop_params), args.repeats)
        print(f"{d:>3} {batched * 1e3:>11.2f} {looped * 1e3:>9.2f} {looped / batched:>15.2f}")
        assert looped > batched, f"the batched experts are not faster than the loop at d={d}"


if __name__ == "__main__":
    main()
