"""Stage `evaluate`: the paper's tables on the synthetic sets, and the Baxter obstacle harness.

`stage` plans and runs the tables; `jobs` is one (method, set, seed) fit and score; `tables` and
`figures` render them; `constants` says what each table runs; `baxter` puts the authors' Baxter
recordings through ingest and train and asks whether a model commits to one side of the box.
"""

from cnep.pipeline import exports

__getattr__, __all__ = exports(__name__, {"stage": ("EvaluateConfig", "evaluate")})
