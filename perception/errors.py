"""Errors of the perception package, and how a refused `torch.load` is said to a user."""

import pickle


class PerceptionError(Exception):
    """Frames or weights cannot be used; the message names the file and says how to fix it."""


def torch_load_problem(exc: Exception) -> str:
    """What went wrong in `torch.load(..., weights_only=True)`, for a user: a refused pickle says what it would have
    loaded and that cnep loads tensors only, without torch's advice to load it with `weights_only=False`."""
    text = str(exc)
    if not (isinstance(exc, pickle.UnpicklingError) and text.startswith("Weights only load failed")):
        return text
    said = [line.strip() for line in text.splitlines()[1:] if line.strip() and "weights_only" not in line]
    what = f" ({said[0].rstrip('.')})" if said else ""
    return f"it holds pickled Python objects beyond tensors{what}, which could run code, and cnep loads tensors only"
