"""Seeded fuzzing of cnep's readers: valid small files built with the project's own writers, mutated (bytes flipped,
inserted, deleted, cut; size fields set to extremes; a decompression bomb put into an MCAP file; JSON values replaced
by hostile ones), each read in a child process under a memory cap, with a time limit and a memory budget per case.
The MCAP files go through what `cnep inspect`, `repair`, `ingest`, `extract` (the summaries, the calibration frames)
and `train` (the training set's summaries, the trajectories) read. A reader may refuse a file only with the project's
errors for it; anything else (another exception, a hang, a blow-up) is a finding.

    python -m tests.fuzz --family mcap --cases 200 --seed 0     # the findings, one JSON line each; exit 1 if any

tests/test_fuzz.py runs a few hundred cases per family; `python -m benchmarks fuzz` runs many more.
"""

from __future__ import annotations

import argparse
import functools
import json
import resource
import signal
import struct
import sys
import tempfile
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

FAMILIES = ("mcap", "json", "safetensors")
EXTREMES = (0, 1, 2**31 - 1, 2**31, 2**32 - 1, 2**32, 2**63 - 1, 2**63, 2**64 - 1)
HOSTILE_VALUES = (
    None,
    True,
    -1,
    0,
    2**64,
    10**400,
    1e308,
    float("nan"),
    float("inf"),
    "",
    "x" * 10_000,
    [],
    {},
    [[[[]]]],
    "[[[[",
)
MEMORY_CAP = 1 << 30  # bytes a child may add to its address space after its imports
CASE_SECONDS = 10  # a case that takes longer is a hang
CASE_MEMORY = 256 << 20  # a case that raises the child's peak resident memory by more is a blow-up (bytes)
BOMB_SIZES = (16 << 20, 128 << 20, 768 << 20)  # what a bomb chunk inflates to (bytes): each within MEMORY_CAP


@dataclass(frozen=True)
class Seed:
    """A valid file to mutate: its name in the case folder, its bytes, the offsets of its size fields (u64, little
    endian) and, for JSON, a function that makes the mutated text consistent again (a checkpoint's checksum)."""

    name: str
    data: bytes
    size_fields: tuple[int, ...] = ()
    restamp: Callable[[dict], dict] | None = None


# --- mutations ----------------------------------------------------------------------------------------------------


def mutate_bytes(data: bytes, rng: np.random.Generator, size_fields: tuple[int, ...]) -> tuple[bytes, str]:
    """One random byte-level change of `data` and a description of it."""
    buf, n = bytearray(data), len(data)
    op = int(rng.integers(6))
    at = int(rng.integers(max(n, 1)))
    if op == 0:
        for _ in range(int(rng.integers(1, 9))):
            k = int(rng.integers(n * 8))
            buf[k // 8] ^= 1 << (k % 8)
        return bytes(buf), "flip bits"
    if op == 1:
        extra = rng.integers(0, 256, size=int(rng.integers(1, 64)), dtype=np.uint8).tobytes()
        return bytes(buf[:at] + extra + buf[at:]), f"insert {len(extra)} bytes at {at}"
    if op == 2:
        stop = min(n, at + int(rng.integers(1, 256)))
        return bytes(buf[:at] + buf[stop:]), f"delete bytes {at}:{stop}"
    if op == 3:
        return bytes(buf[:at]), f"cut at {at}"
    if op == 4 and size_fields:
        field = size_fields[int(rng.integers(len(size_fields)))]
        value = EXTREMES[int(rng.integers(len(EXTREMES)))] if rng.random() < 0.7 else int(rng.integers(0, 2**63))
        buf[field : field + 8] = struct.pack("<Q", value)
        return bytes(buf), f"size field at {field} = {value}"
    start = int(rng.integers(max(n - 8, 1)))
    buf[start : start + 8] = struct.pack("<Q", EXTREMES[int(rng.integers(len(EXTREMES)))])
    return bytes(buf), f"u64 at {start} = extreme"


def mutate_mcap(data: bytes, rng: np.random.Generator, size_fields: tuple[int, ...]) -> tuple[bytes, str]:
    """A zstd chunk of zeros that declares its size truthfully inserted after the header, and half the time the
    footer's summary start set to 0 (a file without a summary: the mcap library then reads every record), in a
    fifth of the cases; else a byte-level change."""
    if rng.random() >= 0.2:
        return mutate_bytes(data, rng, size_fields)
    declared = BOMB_SIZES[int(rng.integers(len(BOMB_SIZES)))]
    header_end = 8 + 9 + struct.unpack_from("<Q", data, 9)[0]
    buf = bytearray(data[:header_end] + bomb_chunk(declared) + data[header_end:])
    no_summary = rng.random() < 0.5
    if no_summary:
        footer = len(buf) - 8 - 20  # the footer's body: summary start, summary offset start, summary CRC
        buf[footer : footer + 20] = bytes(20)
    return bytes(buf), f"a chunk of {declared} zero bytes after the header{', no summary' if no_summary else ''}"


@functools.cache
def bomb_chunk(declared: int) -> bytes:
    """An MCAP chunk record of `declared` zero bytes in a few KB of zstd (no CRC: it is never inflated to check)."""
    from tests.recordings.hostile import chunk_record, zstd_zeros

    return chunk_record(declared, zstd_zeros(declared))


def mutate_json(data: bytes, rng: np.random.Generator, restamp: Callable[[dict], dict] | None) -> tuple[bytes, str]:
    """A hostile value put somewhere in the JSON document `data` (half the time), else a byte-level change."""
    if rng.random() < 0.5:
        return mutate_bytes(data, rng, ())
    doc = json.loads(data)
    node, path = doc, []
    while isinstance(node, dict | list) and node and rng.random() < 0.75:
        key = rng.choice(list(node)) if isinstance(node, dict) else int(rng.integers(len(node)))
        if not isinstance(node[key], dict | list):
            break
        node, path = node[key], [*path, key]
    if isinstance(node, dict | list) and node:
        key = rng.choice(list(node)) if isinstance(node, dict) else int(rng.integers(len(node)))
        value = HOSTILE_VALUES[int(rng.integers(len(HOSTILE_VALUES)))]
        node[key] = value
        path = [*path, key]
    else:
        value = "deep"
        doc = {"deep": [doc] * 2, "nested": "[" * 3000}
    if isinstance(doc, dict) and restamp is not None:
        doc = restamp(doc)
    return json.dumps(doc).encode(), f"set {'/'.join(map(str, path))} to {str(value)[:40]}"


# --- seeds: valid files written by cnep ---------------------------------------------------------------------------


def mcap_size_fields(data: bytes) -> tuple[int, ...]:
    """Offsets of the u64 size fields of an MCAP file's top-level records: every record's length and, in a chunk,
    its uncompressed size and its data's length."""
    fields, pos = [], 8
    while pos + 9 <= len(data):
        opcode, length = struct.unpack_from("<BQ", data, pos)
        fields.append(pos + 1)
        if opcode == 0x06:  # chunk: start, end, uncompressed size, CRC, compression (u32 + text), data length
            body = pos + 9
            (clen,) = struct.unpack_from("<I", data, body + 28)
            fields += [body + 16, body + 32 + clen]
        pos += 9 + length
    return tuple(fields)


def mcap_seeds(folder: Path) -> list[Seed]:
    from cnep.recordings import write_demonstration, write_trajectory
    from tests.recordings.factories import demonstration_factory, trajectory_factory
    from tests.recordings.sources import robot_mcap

    files = {
        "robot.mcap": lambda p: robot_mcap(p, duration_s=0.5, camera_hz=4.0, pose_hz=10.0, gripper_hz=10.0),
        "demonstration.mcap": lambda p: write_demonstration(p, demonstration_factory(steps=6, frame_size=8)),
        "motion.mcap": lambda p: write_demonstration(p, demonstration_factory(steps=8, frames=False)),
        "trajectory.mcap": lambda p: write_trajectory(p, trajectory_factory(steps=4, features=True)),
    }
    seeds = []
    for name, write in files.items():
        write(folder / name)
        data = (folder / name).read_bytes()
        seeds.append(Seed(name, data, mcap_size_fields(data)))
    return seeds


def json_seeds(folder: Path) -> list[Seed]:
    from cnep.models.checkpoint import CHECKSUM_KEY, FORMAT_VERSION, config_checksum
    from cnep.models.config import CNEPConfig, ColumnRoles
    from cnep.runtime.constants import MANIFEST_FORMAT
    from tests.runtime.fakes import camera_spec

    def stamped(config: dict) -> dict:
        return {**config, CHECKSUM_KEY: config_checksum(config)}

    columns = ColumnRoles(width=4, observed=((0, 2),), query=((2, 3),), predicted=((3, 4),))
    model = CNEPConfig(columns=columns, n_experts=2, encoder_widths=(8,), expert_widths=(8,))  # no torch to import
    config = stamped({"format_version": FORMAT_VERSION, "model": model.to_dict()})
    manifest = {
        "format": MANIFEST_FORMAT,
        "format_version": 1,
        "producer": "fuzz",
        "spec": camera_spec().to_dict(),
        "extractor": {},
        "features": {"fp32": {"file": "features.onnx", "identity": {}}},
        "graphs": {"encoder": "encoder.onnx", "decoder": "decoder.onnx"},
        "checkpoint": {},
        "files": {"encoder.onnx": "0" * 64, "decoder.onnx": "0" * 64, "features.onnx": "0" * 64},
    }
    info = {
        "codebase_version": "v2.1",
        "fps": 10,
        "chunks_size": 1000,
        "data_path": "data/chunk-{episode_chunk:03d}/episode_{episode_index:06d}.parquet",
        "features": {"observation.state": {"dtype": "float32", "shape": [8], "names": ["x"] * 8}},
    }
    settings = {"lr": 0.001, "steps": 10, "batch_size": 4}
    return [
        Seed("config.json", json.dumps(config).encode(), restamp=stamped),
        Seed("manifest.json", json.dumps(manifest).encode()),
        Seed("info.json", json.dumps(info).encode()),
        Seed("settings.json", json.dumps(settings).encode()),
    ]


def safetensors_size_fields(data: bytes) -> tuple[int, ...]:
    return (0,)  # the header's length; the sizes inside the header are JSON (mutate_safetensors)


def mutate_safetensors(data: bytes, rng: np.random.Generator) -> tuple[bytes, str]:
    """An extreme value in a tensor's shape or data offsets (half the time), else a byte-level change."""
    (length,) = struct.unpack_from("<Q", data)
    if rng.random() < 0.5 or length > len(data):
        return mutate_bytes(data, rng, safetensors_size_fields(data))
    header = json.loads(data[8 : 8 + length])
    name = rng.choice(sorted(k for k in header if k != "__metadata__"))
    entry = "shape" if rng.random() < 0.5 else "data_offsets"
    values = header[name][entry]
    if values:
        values[int(rng.integers(len(values)))] = (
            EXTREMES[int(rng.integers(len(EXTREMES)))] if rng.random() < 0.8 else -1
        )
    text = json.dumps(header).encode()
    return struct.pack("<Q", len(text)) + text + data[8 + length :], f"{name}.{entry} = {values}"


def safetensors_seeds(folder: Path) -> list[Seed]:
    import torch

    from cnep.models import CNEP, save_checkpoint

    torch.set_num_threads(1)
    from cnep.models.checkpoint import WEIGHTS_FILE
    from tests.models.factories import tiny_config

    torch.manual_seed(0)
    save_checkpoint(CNEP(tiny_config()), folder / "checkpoint")
    data = (folder / "checkpoint" / WEIGHTS_FILE).read_bytes()
    return [Seed(WEIGHTS_FILE, data, safetensors_size_fields(data))]


# --- the readers and the errors they may raise ------------------------------------------------------------------


Allowed = type[Exception] | tuple[type[Exception], ...]


def mcap_readers() -> list[tuple[str, Callable[[Path, Path], object], Allowed]]:
    from cnep.perception import PerceptionError
    from cnep.pipeline.errors import PipelineError
    from cnep.pipeline.extract.stage import calibration_frames, frame_counts
    from cnep.pipeline.train.data import load_training_set
    from cnep.recordings import RecordingError, read_demonstration, read_trajectory
    from cnep.recordings.inspection import format_report, inspect_file
    from cnep.recordings.mcap_source import McapTopics, demonstration_from_mcap
    from cnep.recordings.repair import repair

    robot = McapTopics(image="/robot/camera", pose="/robot/ee", gripper="/robot/joints", gripper_joint="gripper_joint")
    refused = (RecordingError, PipelineError, PerceptionError)

    return [
        ("read_demonstration", lambda path, _: read_demonstration(path), RecordingError),
        ("read_trajectory", lambda path, _: read_trajectory(path), RecordingError),
        ("inspect", lambda path, _: format_report(inspect_file(path)), RecordingError),
        ("repair", lambda path, work: repair(path, work / "repaired.mcap"), RecordingError),
        ("ingest robot MCAP", lambda path, _: demonstration_from_mcap(path, "fuzz", robot), RecordingError),
        ("extract: frame counts", lambda path, _: frame_counts([path]), RecordingError),
        ("extract: calibration frames", lambda path, _: calibration_frames([path], 4), refused),
        ("train: the training set", lambda path, _: load_training_set([path, path]), refused),
    ]


def json_readers() -> dict[str, tuple[str, Callable[[Path, Path], object], Allowed]]:
    from cnep.models import ConfigError
    from cnep.models.checkpoint import checkpoint_model_config
    from cnep.pipeline.cli.train import read_settings
    from cnep.pipeline.errors import PipelineError
    from cnep.recordings import RecordingError
    from cnep.recordings.lerobot import is_lerobot_dataset, plan_lerobot
    from cnep.runtime import PolicyError, read_manifest
    from cnep.runtime.manifest import check_closed

    def lerobot(path: Path, work: Path) -> object:
        meta = work / "dataset" / "meta"
        meta.mkdir(parents=True, exist_ok=True)
        (meta / "info.json").write_bytes(path.read_bytes())
        (meta / "episodes.jsonl").write_text('{"episode_index": 0, "tasks": ["pick"], "length": 6}\n')
        return is_lerobot_dataset(meta.parent) and plan_lerobot(meta.parent)

    def checkpoint(path: Path, _: Path) -> object:
        return checkpoint_model_config(path.parent)

    def manifest(path: Path, _: Path) -> object:
        return check_closed(path.parent, read_manifest(path.parent))

    return {
        "config.json": ("checkpoint config", checkpoint, ConfigError),
        "manifest.json": ("policy manifest", manifest, PolicyError),
        "info.json": ("LeRobot info", lerobot, RecordingError),
        "settings.json": ("train --config", lambda path, _: read_settings(str(path)), PipelineError),
    }


def safetensors_readers() -> list[tuple[str, Callable[[Path, Path], object], Allowed]]:
    from cnep.models import ConfigError, load_checkpoint

    return [("load_checkpoint", lambda path, _: load_checkpoint(path.parent), ConfigError)]


# --- the run ------------------------------------------------------------------------------------------------------


class _Hang(Exception):
    """Raised by the per-case alarm."""


def _alarm(signum: int, frame: object) -> None:
    raise _Hang


def peak_memory() -> int:
    """The most memory this process has held resident so far (bytes)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # Linux counts it in KiB


def cap_memory(extra: int) -> None:
    """Limit this process's address space to what it uses now plus `extra` bytes."""
    with open("/proc/self/statm") as f:
        pages = int(f.read().split()[0])
    now = pages * resource.getpagesize()
    resource.setrlimit(resource.RLIMIT_AS, (now + extra, resource.getrlimit(resource.RLIMIT_AS)[1]))


def run(family: str, cases: int, seed: int) -> tuple[list[dict], int]:
    """Fuzz `family` with `cases` mutated files from `seed`: the findings (one dict each) and the cases run."""
    rng = np.random.default_rng(seed)
    findings: list[dict] = []
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        seeds = {"mcap": mcap_seeds, "json": json_seeds, "safetensors": safetensors_seeds}[family](root)
        readers = {"mcap": mcap_readers, "safetensors": safetensors_readers}.get(family, list)()
        by_name = json_readers() if family == "json" else None
        for declared in BOMB_SIZES if family == "mcap" else ():
            bomb_chunk(declared)  # made before the memory is capped and measured
        cap_memory(MEMORY_CAP)
        signal.signal(signal.SIGALRM, _alarm)
        for case in range(cases):
            chosen = seeds[case % len(seeds)]
            if family == "json":
                data, change = mutate_json(chosen.data, rng, chosen.restamp)
            elif family == "safetensors":
                data, change = mutate_safetensors(chosen.data, rng)
            else:
                data, change = mutate_mcap(chosen.data, rng, chosen.size_fields)
            work = root / f"case{case}"
            target = work / ("checkpoint" if family == "safetensors" else "in") / chosen.name
            target.parent.mkdir(parents=True)
            if family == "safetensors":
                (target.parent / "config.json").write_bytes((root / "checkpoint" / "config.json").read_bytes())
            target.write_bytes(data)
            for name, read, allowed in [by_name[chosen.name]] if by_name else readers:
                start, peak = time.perf_counter(), peak_memory()
                signal.alarm(CASE_SECONDS)
                try:
                    read(target, work)
                except allowed:
                    pass
                except _Hang:
                    findings.append({"case": case, "file": chosen.name, "change": change, "reader": name, "hang": True})
                except BaseException as exc:  # noqa: BLE001 - anything else is what the fuzzing looks for
                    where = traceback.extract_tb(exc.__traceback__)[-1]
                    findings.append(
                        {
                            "case": case,
                            "file": chosen.name,
                            "change": change,
                            "reader": name,
                            "error": f"{type(exc).__name__}: {str(exc)[:200]}",
                            "at": f"{Path(where.filename).name}:{where.lineno}",
                            "seconds": round(time.perf_counter() - start, 3),
                        }
                    )
                finally:
                    signal.alarm(0)
                grew = peak_memory() - peak
                if grew > CASE_MEMORY:
                    findings.append(
                        {"case": case, "file": chosen.name, "change": change, "reader": name, "memory": grew}
                    )
    return findings, cases


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--family", choices=FAMILIES, required=True)
    parser.add_argument("--cases", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    findings, cases = run(args.family, args.cases, args.seed)
    for finding in findings:
        print(json.dumps(finding))
    print(json.dumps({"family": args.family, "cases": cases, "seed": args.seed, "findings": len(findings)}))
    return 1 if findings else 0


if __name__ == "__main__":
    sys.exit(main())
