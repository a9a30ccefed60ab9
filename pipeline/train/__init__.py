"""Stage `train`: trajectory MCAP files -> a checkpoint folder (config.json + model.safetensors).

`stage` drives a run; `data` finds, reads and checks the inputs; `presets` maps a preset onto the
file's columns; `state` keeps the resumable work folder and the log; `parallel` runs under torchrun;
`constants` holds the names and defaults the CLI shows without importing torch.
"""

from cnep.pipeline import exports

__getattr__, __all__ = exports(
    __name__, {"stage": ("TrainStageConfig", "train"), "checkpoint": ("RowMapping", "TrainedModel", "load_trained")}
)
