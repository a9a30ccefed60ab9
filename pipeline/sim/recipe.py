"""The training recipe's reference page, generated from the code: the schedule the training data sets and what each
`cnep sim` task trains on.

`python -m cnep.pipeline.sim.recipe docs/reference/training-recipe.md` writes it (`make docs`; without a path: to
stdout). tests/test_docs.py fails when the committed page differs from `render()`. Importable without torch or the
simulator.
"""

from __future__ import annotations

import sys
from pathlib import Path

from cnep.models.config import CNEPConfig, ConditioningPolicy, TrainConfig
from cnep.models.schedule import (
    BASE_STEPS,
    DRAWS_PER_DEMONSTRATION,
    FEW_DEMONSTRATIONS,
    FIRST_READ_SHARE,
    MAX_VAL_EVERY,
    MAX_WARMUP,
    ONLINE_SHARE,
    VALIDATIONS,
    WARMUP_SHARE,
    schedule_of,
)
from cnep.perception.constants import DEFAULT_VIEWS
from cnep.pipeline.sim.config import PickPlaceConfig, SimConfig, trained_conditioning
from cnep.pipeline.train.config import TrainStageConfig
from cnep.pipeline.train.presets import resolve_preset
from cnep.recordings.constants import FEATURE_DIM, STEP_DIM

SIM_COMMANDS = (SimConfig, PickPlaceConfig)  # `cnep sim TASK`'s configs, one per task with a command of its own
EXAMPLE_SIZES = (8, 36, 63, 64, 160, 307, 1_000, 5_000)  # training demonstrations the schedule's table shows

HEADER = """\
# The training recipe

What every trainer trains with (`cnep train` without options, `cnep sim`, `cnep demo`, the Baxter example),
generated from the code (`make docs` regenerates this page; do not edit it by hand). How to change a setting:
[training](../how-to/train.md); every option: [the CLI reference](cli.md).
"""


def render() -> str:
    """The whole page (Markdown)."""
    model, training = CNEPConfig(), TrainConfig()
    lines = [
        HEADER,
        "## The schedule",
        "",
        f"Left unset, the training steps, the warm-up and the validation interval follow from the number of "
        f"demonstrations trained on (those not held out for validation; models.schedule): {BASE_STEPS} steps, or "
        f"more where each training demonstration would be drawn fewer than {DRAWS_PER_DEMONSTRATION} times in "
        f"batches of {training.batch_size} samples; a warm-up of {WARMUP_SHARE:.0%} of the steps, at most "
        f"{MAX_WARMUP}; {VALIDATIONS} validations, at most every {MAX_VAL_EVERY} steps. Given steps keep the rule "
        f"for the other two; config.json records the schedule's inputs, its values and which were given "
        f"([checkpoint format](checkpoint.md)). Early stopping after {training.patience} validations without "
        f"improvement only cuts runs longer than the schedule's {VALIDATIONS} validations.",
        "",
        f"Left unset, the feature components follow from the same number: trained on fewer than {FEW_DEMONSTRATIONS} "
        "demonstrations, a model that observes more columns than that which it does not predict (a camera's features) "
        "reads them as their principal components, as many as the demonstrations; else every column as it is. A few "
        "dozen scenes differ along at most that many directions of the features, and the rest would tell each "
        "training scene apart ([concepts](../concepts.md)). Each view of a demonstration's frames its trajectory file "
        "holds (`cnep extract --views`) counts as one more: the table's training demonstrations are those and their "
        f"views. `cnep extract` draws {DEFAULT_VIEWS} views of each where it extracts fewer than {FEW_DEMONSTRATIONS} "
        "demonstrations at once, none where more. `--feature-components K` reads K components whatever the data, "
        "`--feature-components 0` every column as it is.",
        "",
        "Left unset, the online contexts follow from the columns: a model that observes columns it does not predict "
        "(a camera's features) is a policy, conditioned step by step on its first `anchors` and latest `window` "
        f"observations; {ONLINE_SHARE:.0%} of its training contexts are that set at a step (the first, its first "
        f"read, in {FIRST_READ_SHARE:.0%} of them), their targets the steps after it. A motion-only model keeps the "
        "paper's random contexts (0%). `--online-contexts S` gives the share "
        "([concepts](../concepts.md#online-conditioning-the-gate-over-time)).",
        "",
        f"| training demonstrations | steps | warm-up | validation every | components of {FEATURE_DIM} features |",
        "|---|---|---|---|---|",
    ]
    images = CNEPConfig(columns=resolve_preset(TrainStageConfig.layout, STEP_DIM, Path("trajectories")).roles)
    for size in EXAMPLE_SIZES:
        made = schedule_of(training, size, model=images)
        components = made.feature_components or "all, as they are"
        lines.append(f"| {size} | {made.steps} | {made.warmup_steps} | {made.val_every} | {components} |")
    lines += [
        "",
        "## `cnep sim`: what differs per task",
        "",
        "Each task's CNEP and matched CNMP train with `cnep train`'s defaults and schedule "
        f"(layout `{TrainStageConfig.layout}`); what differs per task is in the table: its data (the demonstrations it "
        "generates, the experts for its behaviours). The loss and the conditioning are `cnep train`'s ([how they were "
        "chosen](../results-tuning.md#how-a-pick-and-place-policys-loss-and-conditioning-were-chosen)); the "
        "conditioning is what their policies run with (config.json, the manifest). `cnep train`'s own settings are in "
        "the first row.",
        "",
        "| | demonstrations | CNEP experts | assignment | beta-NLL | conditioning window | anchors |",
        "|---|---|---|---|---|---|---|",
        f"| `cnep train` | yours | {model.n_experts} | {model.assignment} | {training.nll_beta:g} | "
        f"{ConditioningPolicy().window} | {ConditioningPolicy().anchors} |",
    ]
    for command in SIM_COMMANDS:
        default = command(out=Path("out"))
        conditioning = trained_conditioning(default)
        lines.append(
            f"| `cnep sim {command.TASK}` | {default.demonstrations} | {default.experts} | {default.assignment} | "
            f"{default.nll_beta:g} | {conditioning.window} | {conditioning.anchors} |"
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str]) -> int:
    page = render()
    if argv:
        Path(argv[0]).write_text(page)
    else:
        sys.stdout.write(page)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
