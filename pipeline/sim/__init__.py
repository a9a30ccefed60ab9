"""Stage `sim`: policies in closed loop in the simulator (cnep.sim, the `sim` extra): `run_sim` from nothing to the
table (`cnep sim obstacle`), `run_pick_place` the same for the pick-and-place task (`cnep sim pick-place`),
`run_eval` for a given policy (`cnep sim eval`), `evaluate_policy` the loop itself.
"""

from cnep.pipeline import exports

__getattr__, __all__ = exports(
    __name__,
    {
        "config": ("EvalConfig", "LoopSettings", "PickPlaceConfig", "SimConfig"),
        "evaluate": ("run_eval",),
        "loop": ("evaluate_policy",),
        "pick_stage": ("run_pick_place",),
        "stage": ("run_sim",),
    },
)
