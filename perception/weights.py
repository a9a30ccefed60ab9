"""Weights of the feature network, chosen explicitly: `imagenet`, a path to a state dict, or `random`.

`imagenet` is looked up like torchvision does (the torch hub cache) and downloaded there when missing,
unless downloads are off (`CNEP_OFFLINE`, `cnep extract --offline`).

A `Weights` holds the state dict of MobileNet-v2's `features` block (keys like `0.0.weight`), the
name written into the extractor identity and the pooling the network uses with them (perception.network):
`global` for ImageNet weights and other files, `cells` for seeded random weights and for files saved from
them (`save_state_dict` writes the pooling into the file under POOLING_KEY).
"""

from __future__ import annotations

import hashlib
import io
import logging
import os
import re
import socket
import sys
import time
import urllib.error
import urllib.parse
import urllib.request
from dataclasses import dataclass
from pathlib import Path

import torch
from tqdm import tqdm

from cnep.outputs import atomic_file, write_atomically
from cnep.perception.calibration import low_pass
from cnep.perception.constants import (
    ARCHITECTURES,
    CONNECT_TIMEOUT_S,
    DOWNLOAD_TIMEOUT_S,
    IMAGENET_WEIGHT_FILES,
    OFFLINE_ENV_VAR,
    WEIGHTS_ENV_VAR,
)
from cnep.perception.errors import PerceptionError, torch_load_problem
from cnep.perception.network import mobilenet_v2_features

_FEATURES_PREFIX = "features."  # keys of a full torchvision mobilenet_v2 state dict
POOLING_KEY = "cnep.pooling"  # the pooling a saved file's weights go with (absent: `global`)
HASH_PREFIX = re.compile(r"-([a-f0-9]*)\.")  # torchvision file names end in -<first hex digits of the sha256>.pth

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Weights:
    """A `features` state dict, its name (`imagenet:<file>`, `path:<file>` or `random:seed=<n>`) and the pooling
    that goes with it (`global` or `cells`)."""

    name: str
    state_dict: dict[str, torch.Tensor]
    pooling: str = "global"

    @property
    def is_random(self) -> bool:
        """True for seeded random initialisation (its batch-norm statistics need re-estimating)."""
        return self.name.startswith("random:")


def resolve_weights(spec: str | Path, seed: int = 0) -> Weights:
    """Turn `imagenet`, `random` or a state-dict path into Weights; `seed` only matters for `random`."""
    if str(spec) == "random":
        return Weights(f"random:seed={seed}", random_state_dict(seed), pooling="cells")
    if str(spec) == "imagenet":
        path = find_imagenet_weights()
        return Weights(f"imagenet:{path.name}", *load_weights_file(path))
    path = Path(spec)
    if not path.is_file():
        raise PerceptionError(
            f"weights file {path} does not exist; pass `imagenet`, `random` or the path of a "
            f"MobileNet-v2 state dict (.pth/.pt or .safetensors)"
        )
    return Weights(f"path:{path.name}", *load_weights_file(path))


def imagenet_search_paths() -> list[Path]:
    """Where ImageNet weights are looked for, in order: the environment variable, then the torch hub cache."""
    paths = [Path(os.environ[WEIGHTS_ENV_VAR]).expanduser()] if os.environ.get(WEIGHTS_ENV_VAR) else []
    return paths + [hub_checkpoints() / name for name in IMAGENET_WEIGHT_FILES]


def hub_checkpoints() -> Path:
    """torchvision's weight cache: `torch.hub.get_dir()/checkpoints` (i.e. `$TORCH_HOME/hub/checkpoints`)."""
    return Path(torch.hub.get_dir()) / "checkpoints"


def offline() -> bool:
    """True when the environment forbids downloads (OFFLINE_ENV_VAR set to anything but "", 0, false, no)."""
    return os.environ.get(OFFLINE_ENV_VAR, "").strip().lower() not in ("", "0", "false", "no")


def find_imagenet_weights(download: bool | None = None) -> Path:
    """The first existing ImageNet weight file; if there is none, download the first of IMAGENET_WEIGHT_FILES into
    the hub cache (as torchvision does) unless `download` is False (None: unless `offline()`).

    A PerceptionError says where to put the file, where to get it and what else to do.
    """
    candidates = imagenet_search_paths()
    for path in candidates:
        if path.is_file():
            return path
    if os.environ.get(WEIGHTS_ENV_VAR):
        raise PerceptionError(
            f"{WEIGHTS_ENV_VAR}={os.environ[WEIGHTS_ENV_VAR]} is not a file; point it at a "
            f"MobileNet-v2 ImageNet state dict"
        )
    if download is None:
        download = not offline()
    if download:
        name, url = next(iter(IMAGENET_WEIGHT_FILES.items()))
        return download_weights(url, hub_checkpoints() / name)
    names = " or ".join(IMAGENET_WEIGHT_FILES)
    urls = " or ".join(IMAGENET_WEIGHT_FILES.values())
    raise PerceptionError(
        f"ImageNet weights for MobileNet-v2 not found and downloading is off ({OFFLINE_ENV_VAR} or "
        f"--offline): put {names} in {hub_checkpoints()} (or set {WEIGHTS_ENV_VAR} to the file); "
        f"download it from {urls} on a machine with internet access, or choose weights `random` "
        f"(seeded) explicitly"
    )


def download_weights(url: str, dst: Path, timeout_s: float = DOWNLOAD_TIMEOUT_S) -> Path:
    """Download `url` to `dst` as torchvision does: a progress bar, the sha256 prefix in the file name checked,
    written to a temporary name in the same folder and renamed when complete (cnep.outputs). Returns `dst`.

    The bar shows on a terminal only, and not when INFO logging is off (`cnep -q`); elsewhere one log line
    before and one after.
    """
    match = HASH_PREFIX.search(dst.name)
    alternatives = (
        f"put the file there yourself (from a machine with internet access), set {WEIGHTS_ENV_VAR} to "
        f"a copy of it, or choose weights `random` (seeded; `--weights random`) explicitly; `--offline` (or "
        f"{OFFLINE_ENV_VAR}=1) never tries the download"
    )
    digest = hashlib.sha256()
    unreachable = connection_refused(url)  # seconds, where urllib would wait for the read timeout per address
    if unreachable is not None:
        raise PerceptionError(f"cannot download ImageNet weights from {url} into {dst} ({unreachable}); {alternatives}")
    try:
        dst.parent.mkdir(parents=True, exist_ok=True)
        with atomic_file(dst) as tmp, urllib.request.urlopen(url, timeout=timeout_s) as response:
            size = int(response.headers.get("Content-Length") or 0) or None
            log.info(
                "downloading ImageNet weights %s (%s) into %s",
                url,
                f"{size / 1e6:.1f} MB" if size else "size unknown",
                dst,
            )
            show = sys.stderr.isatty() and log.isEnabledFor(logging.INFO)
            with tqdm(
                total=size, unit="B", unit_scale=True, unit_divisor=1024, desc="download", disable=not show
            ) as bar:
                while chunk := response.read(1 << 16):
                    tmp.write(chunk)
                    digest.update(chunk)
                    bar.update(len(chunk))
            if match and not digest.hexdigest().startswith(match.group(1)):
                raise PerceptionError(
                    f"the download from {url} is corrupt: its sha256 {digest.hexdigest()[:16]}... does "
                    f"not start with {match.group(1)!r} as its name says; nothing was saved to {dst}; "
                    f"try again, or {alternatives}"
                )
    except (urllib.error.URLError, OSError) as exc:
        reason = getattr(exc, "reason", None) or exc.strerror or exc
        raise PerceptionError(
            f"cannot download ImageNet weights from {url} into {dst} ({reason}); {alternatives}"
        ) from None
    log.info("saved %s (sha256 %s...)", dst, digest.hexdigest()[:12])
    return dst


def connection_refused(url: str, timeout_s: float = CONNECT_TIMEOUT_S) -> str | None:
    """Why no connection to `url`'s server (or the proxy the environment names for it) opens within `timeout_s`
    seconds, trying its addresses in turn; None when one opens. A machine without network fails here in seconds."""
    parsed = urllib.parse.urlsplit(url)
    proxy = urllib.request.getproxies().get(parsed.scheme)
    target = urllib.parse.urlsplit(proxy if proxy and not urllib.request.proxy_bypass(parsed.hostname or "") else url)
    host, port = target.hostname or "", target.port or (443 if target.scheme == "https" else 80)
    deadline = time.monotonic() + timeout_s
    try:
        addresses = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except OSError as exc:
        return f"{host}: {exc.strerror or exc}"
    for family, kind, protocol, _, address in addresses:
        left = deadline - time.monotonic()
        if left <= 0:
            break
        try:
            with socket.socket(family, kind, protocol) as probe:
                probe.settimeout(left)
                probe.connect(address)
            return None
        except OSError:
            continue
    return f"no connection to {host} port {port} within {timeout_s:.0f} s: no network here?"


def seeded_features(seed: int) -> torch.nn.Module:
    """MobileNet-v2 `features` as torchvision initialises them, seeded, without touching the global RNG."""
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        return mobilenet_v2_features()


def random_state_dict(seed: int) -> dict[str, torch.Tensor]:
    """`seeded_features(seed)` with their early 3x3 kernels made low-pass (perception.calibration.low_pass)."""
    features = seeded_features(seed)
    low_pass(features)
    return features.state_dict()


def load_state_dict(path: Path) -> dict[str, torch.Tensor]:
    """Load a MobileNet-v2 state dict (full model or `features` only) from .pth/.pt (weights_only) or .safetensors.

    Returns the `features` part with keys relative to it, checked against the architecture.
    """
    return load_weights_file(path)[0]


def load_weights_file(path: Path) -> tuple[dict[str, torch.Tensor], str]:
    """`load_state_dict`'s state dict and the pooling stored with it (POOLING_KEY; `global` when absent)."""
    try:
        if path.suffix == ".safetensors":
            from safetensors.torch import load_file

            raw = load_file(str(path))
        else:
            raw = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # pickle, zip and safetensors errors have no common base class
        raise PerceptionError(
            f"cannot load weights file {path}: {torch_load_problem(exc)}; expected a state dict saved with "
            f"torch.save(model.state_dict(), path)"
        ) from exc
    if not isinstance(raw, dict):
        raise PerceptionError(
            f"weights file {path} holds a {type(raw).__name__}, not a state dict; save it with "
            f"torch.save(model.state_dict(), path)"
        )
    pooling = raw.get(POOLING_KEY, "global")
    if pooling not in ARCHITECTURES:
        raise PerceptionError(
            f"weights file {path}: {POOLING_KEY} is {pooling!r}, expected one of {tuple(ARCHITECTURES)}"
        )
    if any(key.startswith(_FEATURES_PREFIX) for key in raw):
        raw = {k[len(_FEATURES_PREFIX) :]: v for k, v in raw.items() if k.startswith(_FEATURES_PREFIX)}
    reference = mobilenet_v2_features().state_dict()
    missing = sorted(set(reference) - set(raw))
    if missing:
        raise PerceptionError(
            f"weights file {path} is not a MobileNet-v2 state dict: {len(missing)} keys missing "
            f"(e.g. features.{missing[0]})"
        )
    for key, tensor in reference.items():
        if not isinstance(raw[key], torch.Tensor) or raw[key].shape != tensor.shape:
            shape = getattr(raw[key], "shape", type(raw[key]).__name__)
            raise PerceptionError(
                f"weights file {path}: features.{key} has shape {tuple(shape)}, MobileNet-v2 "
                f"expects {tuple(tensor.shape)}"
            )
    return {key: raw[key].to(tensor.dtype) for key, tensor in reference.items()}, pooling


def save_state_dict(state_dict: dict[str, torch.Tensor], path: Path, pooling: str = "global") -> None:
    """Write a `features` state dict as a torchvision-style file (keys `features.*`, plus POOLING_KEY unless the
    pooling is `global`), atomically.

    Serialised in memory first: torch.save writing into a full disk fails with its own error, not the OSError
    that names the file.
    """
    buffer = io.BytesIO()
    saved: dict[str, object] = {_FEATURES_PREFIX + k: v.detach().clone() for k, v in state_dict.items()}
    if pooling != "global":
        saved[POOLING_KEY] = pooling
    torch.save(saved, buffer)
    write_atomically(path, buffer.getvalue())


def state_dict_sha256(state_dict: dict[str, torch.Tensor]) -> str:
    """sha256 over every tensor's name, dtype, shape and bytes, in key order (hex string of 64 characters)."""
    digest = hashlib.sha256()
    for key in sorted(state_dict):
        tensor = state_dict[key].detach().contiguous().cpu()
        digest.update(f"{key}|{tensor.dtype}|{tuple(tensor.shape)}|".encode())
        digest.update(tensor.numpy().tobytes())
    return digest.hexdigest()
