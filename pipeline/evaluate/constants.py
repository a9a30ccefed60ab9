"""Constants of `cnep evaluate`: what each table runs, the baselines' sizes, run budgets, the paper's numbers."""

from __future__ import annotations

TABLES = ("comparison", "ablation", "experts", "commitment")

# Columns (data sets) of each table; `--quick` keeps only QUICK_SETS of them.
TABLE_SETS = {
    "comparison": ("unimodal", "bimodal", "multimodal", "multimodal6"),
    "ablation": ("unimodal", "bimodal", "multimodal"),
    "experts": ("bimodal", "multimodal", "multimodal6"),
    "commitment": ("bimodal", "multimodal", "multimodal6"),
}
QUICK_SETS = ("bimodal", "multimodal")
SET_TITLES = {"unimodal": "Unimodal", "bimodal": "Bimodal", "multimodal": "4 modes", "multimodal6": "6 modes"}

# Experts of "the" CNEP of a set (comparison and ablation tables; its CNMP is parameter-matched to it).
# 6 modes take 8 experts so that the comparison's model is also the experts table's CNEP-8.
CNEP_EXPERTS = {"unimodal": 2, "bimodal": 2, "multimodal": 4, "multimodal6": 8}
EXPERT_COUNTS = (2, 4, 8)

# The authors' baseline sizes (uni / bi / multi); the 6-mode set has no published value: we use the
# 4-mode set's ProMP size and two Gaussians per mode.
PROMP_WEIGHTS = {"unimodal": 10, "bimodal": 30, "multimodal": 8, "multimodal6": 8}
GMM_COMPONENTS = {"unimodal": 10, "bimodal": 20, "multimodal": 6, "multimodal6": 12}

# Budgets. Full: every set of the table; quick: what CI runs.
# Training steps per set (`--steps` sets one value for all): the paper tables' 4 and 6 modes train 2.5 times the
# models.TrainConfig default (docs/concepts.md); the unimodal and bimodal sets are learnt in the default.
STEPS = {"unimodal": 4_000, "bimodal": 4_000, "multimodal": 10_000, "multimodal6": 10_000}
# Early stopping (models.TrainConfig.patience): a network stops after this many validations (every 500 steps)
# without a lower validation error; the model kept is its best, as without the stop. On the full schedule the
# best validation comes about halfway on 4 modes and no later one beats it, so a stop keeps the model the full
# schedule would have kept.
PATIENCE = 4
# The paper's plain likelihood (models.TrainConfig.nll_beta 0) for every network of its tables, whatever the library's
# default weighting.
PAPER_NLL_BETA = 0.0
SEEDS = 1  # the default `cnep evaluate` (comparison); the full run uses --seeds 2
QUERIES = 50
QUICK_STEPS = 1_500
QUICK_SEEDS = 1
QUICK_QUERIES = 20
# What `cnep evaluate --quick` says under its tables: its short runs check the set-up, not the paper's claims.
QUICK_NOTE = (
    "quick run: {seeds} seed(s), {steps} training steps, {queries} queries per protocol: it checks the set-up and "
    "does not reproduce the paper's ordering (with this little training the CNEP can score below the CNMP and the "
    "GMM); the full tables: cnep evaluate --table all"
)
JOBS = 2  # worker processes (one thread each)
LOCAL = "local"  # the executor of `jobs` worker processes on this machine
EXECUTORS = (LOCAL, "dask", "ray")  # where the fits run (pipeline.evaluate.executors)
# Networks of one shape and schedule on one set trained as one batched computation (pipeline.evaluate.jobs): a few
# give most of what batching gives (benchmarks/bench_training.py), and units stay short enough to keep the workers
# evenly loaded.
UNIT_NETWORKS = 3
# A network job reports its progress every this many training steps: seconds apart, so the bar moves even on an
# oversubscribed machine.
REPORT_STEPS = 100

SAMPLES_IN_FIGURE = 3  # paper queries drawn per data set in the figures (first seed)
DEFAULT_OUT = "cnep-evaluation"

# The paper's MSE (mean, std) per table, row and set (Tables "MSE over generated trajectories ...").
PAPER = {
    "comparison": {
        "ProMP": {"unimodal": (0.017, 0.010), "bimodal": (0.312, 0.314), "multimodal": (0.199, 0.191)},
        "GMM-GMR": {"unimodal": (0.017, 0.009), "bimodal": (0.096, 0.120), "multimodal": (0.162, 0.065)},
        "CNMP": {"unimodal": (0.015, 0.006), "bimodal": (0.043, 0.078), "multimodal": (0.112, 0.074)},
        "CNEP": {"unimodal": (0.015, 0.005), "bimodal": (0.013, 0.013), "multimodal": (0.027, 0.042)},
    },
    "ablation": {
        "CNEP-Uni": {"unimodal": (0.042, 0.042), "bimodal": (0.185, 0.057), "multimodal": (0.120, 0.079)},
        "CNEP-UnSpec": {"unimodal": (0.033, 0.031), "bimodal": (0.069, 0.096), "multimodal": (0.050, 0.077)},
        "CNEP-Rec": {"unimodal": (0.031, 0.028), "bimodal": (0.113, 0.045), "multimodal": (0.064, 0.069)},
        "CNEP-MoE": {"unimodal": (0.046, 0.049), "bimodal": (0.061, 0.071), "multimodal": (0.040, 0.061)},
        "CNEP": {"unimodal": (0.046, 0.049), "bimodal": (0.058, 0.071), "multimodal": (0.028, 0.049)},
    },
    "experts": {
        "CNEP-2": {"bimodal": (0.005, 0.087), "multimodal": (0.045, 0.038), "multimodal6": (0.063, 0.167)},
        "CNEP-4": {"bimodal": (0.005, 0.090), "multimodal": (0.042, 0.038), "multimodal6": (0.033, 0.148)},
        "CNEP-8": {"bimodal": (0.004, 0.048), "multimodal": (0.042, 0.040), "multimodal6": (0.032, 0.168)},
    },
}
