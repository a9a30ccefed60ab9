"""Stage `sim`: policies in closed loop in the simulator (cnep.sim, the `sim` extra): `run_sim` from nothing to the
table for any task (`cnep sim obstacle`, `cnep sim pick-place`), `run_grid` the benchmark's grid of them (`cnep sim
grid`), `run_eval` for a given policy (`cnep sim eval`), `evaluate_policy` the loop itself, `SelectionSettings` how
`cnep sim` chooses the checkpoint it keeps.
"""

from cnep.pipeline import exports

__getattr__, __all__ = exports(
    __name__,
    {
        "config": ("EvalConfig", "LoopSettings", "PickPlaceConfig", "SimConfig"),
        "evaluate": ("run_eval",),
        "grid": ("run_grid",),
        "grid_config": ("GridConfig",),
        "loop": ("evaluate_policy",),
        "stage": ("run_sim",),
        "validation": ("SelectionSettings",),
    },
)
