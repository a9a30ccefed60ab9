"""Stage `train`: trajectory MCAP files -> a checkpoint folder (config.json + model.safetensors).

`stage` drives a run; `config` holds its settings and their defaults (`TrainStageConfig`, read by the CLI
without torch); `data` finds, reads and checks the inputs; `presets` maps a preset onto the file's columns;
`state` keeps the resumable work folder and the log; `parallel` runs under torchrun; `checkpoint` loads a
finished checkpoint with its columns (`load_trained`); `constants` holds the names the CLI shows.
"""

from cnep.pipeline import exports

__getattr__, __all__ = exports(
    __name__,
    {
        "config": ("TrainStageConfig",),
        "stage": ("train",),
        "checkpoint": ("RowMapping", "TrainedModel", "load_trained"),
    },
)
