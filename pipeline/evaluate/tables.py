"""Markdown rendering of an evaluated table (the dict of pipeline.evaluate.assemble), the paper's numbers beside
ours."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cnep.outputs import write_output
from cnep.pipeline.evaluate.constants import PAPER, SET_TITLES

TITLES = {
    "comparison": "Comparison with the baselines: MSE over generated trajectories conditioned from intermediate points",
    "ablation": "Influence of the loss components (and winner-take-all vs mixture at inference)",
    "experts": "Influence of the number of experts",
    "commitment": "Commitment: conditioned only on a point that several modes share, one demonstrated mode or "
    "their average?",
}
COMMITMENT_NOTE = (
    "Each query conditions on one point that two or more modes share (a crossing of their mean trajectories, a "
    "shared start or end; models.evaluation.shared_queries) and nothing else. Valid: the generated trajectory stays "
    "within the band (3 within-mode standard deviations of the set) of one training demonstration at every step, "
    "that demonstration passing within the band of the point. MSE and max deviation: to the nearest training "
    "demonstration of any mode."
)
PROTOCOL_TITLES = {
    "paper": "Paper protocol (conditioning points between two modes; truth: the training demonstration nearest to "
    "them)",
    "heldout": "Held-out protocol (conditioning points of unseen test demonstrations; truth: that demonstration)",
}
PAPER_NOTE = (
    "The paper's numbers are its Tables' MSE (mean ± std), measured by the authors' notebooks, which chose the "
    "demonstration nearest to the generated trajectory and reported a mean absolute error (docs/concepts.md); "
    "they are printed for reference, not as a like-for-like comparison."
)


def write_text(path: Path, text: str) -> None:
    """Write a text file atomically (temporary name in the same folder, then rename), named in its folder's record."""
    write_output(path, text.encode())


def _pm(mean: float, std: float, digits: int) -> str:
    if not np.isfinite(mean):
        return "n/a"
    return f"{mean:.{digits}f} ± {std:.{digits}f}"


def _cell(cell: dict, metric: str, paper: tuple[float, float] | None = None) -> str:
    digits = 2 if metric == "mode_accuracy" else 4
    text = _pm(cell[metric], cell[f"{metric}_std"], digits)
    if cell["failures"]:
        text += f" ({cell['failures']} non-finite)"
    if paper is not None:
        text += f" (paper {paper[0]:.3f} ± {paper[1]:.3f})"
    return text


def _grid(data: dict, protocol: str, metric: str, with_paper: bool) -> list[str]:
    sets = data["sets"]
    paper = PAPER.get(data["table"], {})
    lines = ["| Method | " + " | ".join(SET_TITLES[s] for s in sets) + " |", "|---" * (len(sets) + 1) + "|"]
    for row in data["rows"]:
        cells = data["results"][protocol].get(row, {})
        texts = [
            _cell(cells[s], metric, paper.get(row, {}).get(s) if with_paper else None) if s in cells else ""
            for s in sets
        ]
        lines.append(f"| {row} | " + " | ".join(texts) + " |")
    return lines


def _commitment_grid(data: dict, metric: str) -> list[str]:
    sets = data["sets"]
    lines = ["| Method | " + " | ".join(SET_TITLES[s] for s in sets) + " |", "|---" * (len(sets) + 1) + "|"]
    for row in data["rows"]:
        texts = []
        for s in sets:
            cell = data["results"]["commitment"][row][s]
            if metric == "valid":
                per_seed = ", ".join(f"{round(v * n)}/{n}" for v, n in zip(cell["valid_per_seed"], cell["queries"]))
                text = f"{100 * cell['valid']:.0f}% ({per_seed})"
            else:
                text = _pm(cell[metric], cell[f"{metric}_std"], 4 if metric == "mse" else 3)
            texts.append(text + (f" ({cell['failures']} non-finite)" if cell["failures"] and metric == "valid" else ""))
        lines.append(f"| {row} | " + " | ".join(texts) + " |")
    bands = " | ".join(
        ", ".join(f"{b:.3f}" for b in data["results"]["commitment"][data["rows"][0]][s]["band"]) for s in sets
    )
    return lines + [f"| band (per seed) | {bands} |"] if metric == "valid" else lines


def _training(data: dict) -> list[str]:
    sets = data["sets"]
    lines = ["| Method | " + " | ".join(SET_TITLES[s] for s in sets) + " |", "|---" * (len(sets) + 1) + "|"]
    for row in data["rows"]:
        texts = []
        for s in sets:
            info = data["training"].get(row, {}).get(s)
            if info is None:
                texts.append("")
                continue
            text = f"fit {np.mean(info['fit_seconds']):.1f} s"
            if "parameters" in info:
                usage = "/".join(f"{u:.2f}" for u in info["final_usage"][0])
                text += (
                    f", {info['parameters']} params, {np.mean(info['steps']):.0f} steps, "
                    f"val {np.mean(info['best_val_error']):.4f}, usage {usage}"
                )
            texts.append(text)
        lines.append(f"| {row} | " + " | ".join(texts) + " |")
    return lines


def to_markdown(data: dict) -> str:
    s = data["settings"]
    stop = f", early stop after {s['patience']} validations without improvement" if s.get("patience") else ""
    lines = [
        f"# {TITLES[data['table']]}",
        "",
        f"{s['seeds']} seed(s) x {s['queries']} queries per protocol and set; training steps per network: "
        f"{', '.join(f'{SET_TITLES[k]} {v}' for k, v in s['steps'].items())}"
        f"{' (--quick)' if s['quick'] else ''}{stop}; written {data['wall_seconds']:.0f} s after the run started "
        f"({s['jobs']} worker process(es)).",
        "Cells: MSE and MAE as mean ± std over all queries of all seeds; mode accuracy (the generated trajectory is "
        "nearest to a training demonstration of the truth's mode) as mean ± std over seeds.",
        "",
    ]
    if data["table"] == "commitment":
        lines += ["## Commitment protocol", "", COMMITMENT_NOTE, "", "### Valid (share of all queries; per seed)", ""]
        lines += _commitment_grid(data, "valid")
        lines += ["", "### MSE to the nearest demonstration", ""] + _commitment_grid(data, "mse")
        lines += ["", "### Max deviation from the nearest demonstration", ""]
        lines += _commitment_grid(data, "max_deviation") + [""]
    for protocol, title in PROTOCOL_TITLES.items():
        lines += [
            f"## {title}",
            "",
            "### MSE" + (" (the paper's number beside ours)" if protocol == "paper" else ""),
            "",
        ]
        lines += _grid(data, protocol, "mse", with_paper=protocol == "paper")
        lines += ["", "### MAE", ""] + _grid(data, protocol, "mae", False)
        lines += ["", "### Mode accuracy", ""] + _grid(data, protocol, "mode_accuracy", False) + [""]
    lines += ["## Training (seed means; usage: mean gate per expert at the last validation, seed 0)", ""]
    lines += _training(data) + ["", PAPER_NOTE, ""]
    return "\n".join(lines)
