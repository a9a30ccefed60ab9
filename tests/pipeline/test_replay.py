"""The replay stage: the .rrd read back without a GUI holds what the gate decided, step by step."""

import datetime as dt
import logging
import shutil
import socket
import subprocess
import sys
import time
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

import cnep.pipeline.replay.viewer as L
from cnep.models import CNEPConfig, ColumnRoles, ConditioningPolicy, build_model, save_checkpoint
from cnep.outputs import RECORD_FILE
from cnep.pipeline.cli.main import main
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.replay.decisions import decisions_path, read_decisions
from cnep.pipeline.replay.rerun_log import first_read_text, serve, viewer_reachable
from cnep.pipeline.replay.stage import replay
from cnep.pipeline.replay.viewer import SURE_GATE
from cnep.recordings import Episode, Trajectory, read_events, write_trajectory
from cnep.recordings.constants import BLOCKS_FULL, BLOCKS_MOTION, MOTION_DIM, STEP_DIM

RERUN = Path(sys.executable).parent / "rerun"
N_EXPERTS = 3


@pytest.fixture(autouse=True)
def rerun_env(tmp_path, monkeypatch):
    """The rerun CLI (used by merge and verify) writes analytics under HOME unless CI is set."""
    home = tmp_path / "home"
    home.mkdir()
    monkeypatch.setenv("CI", "1")
    monkeypatch.setenv("HOME", str(home))
    torch.set_num_threads(1)


def jpeg(value: int) -> bytes:
    ok, buf = cv2.imencode(".jpg", np.full((12, 16, 3), value % 256, np.uint8), [cv2.IMWRITE_JPEG_QUALITY, 80])
    assert ok
    return buf.tobytes()


def motion_rows(steps: int, seed: int) -> np.ndarray:
    """(steps, 8): xyz jumping between two regions every 10 steps (so the gate switches), unit quaternion, gripper."""
    rng = np.random.default_rng(seed)
    data = np.zeros((steps, MOTION_DIM), np.float32)
    region = np.where((np.arange(steps) // 10) % 2 == 0, 1.0, -1.0)
    data[:, :3] = region[:, None] + 0.05 * rng.standard_normal((steps, 3))
    data[:, 6] = 1.0
    data[:, 7] = rng.uniform(0, 1, steps)
    return data


def trajectory(
    steps: int = 40,
    seed: int = 0,
    frames: bool = True,
    width: int = MOTION_DIM,
    name: str = "ep",
    extractor: dict | None = None,
) -> Trajectory:
    data = motion_rows(steps, seed)
    if width == STEP_DIM:
        data = np.concatenate(
            [np.abs(np.random.default_rng(seed).normal(size=(steps, 1280))).astype(np.float32), data], 1
        )
        extractor = extractor or {"architecture": "mobilenet_v2", "weights": "random"}
    return Trajectory(
        episode=Episode(episode_id=name, fps=10.0),
        timestamps_ns=1_700_000_000_000_000_000 + np.arange(steps, dtype=np.int64) * 100_000_000,
        data=data,
        frames=[jpeg(7 * k + seed) for k in range(steps)] if frames else None,
        extractor=extractor,
    )


def make_checkpoint(directory: Path, extra: dict | None = None) -> Path:
    """An untrained (seeded) 8-column model whose gate tells the two xyz regions of `motion_rows` apart."""
    columns = ColumnRoles(width=MOTION_DIM, observed=((0, MOTION_DIM),), predicted=((0, MOTION_DIM),))
    config = CNEPConfig(
        columns=columns, n_experts=N_EXPERTS, encoder_widths=(16, 16), expert_widths=(16, 16), time_frequencies=2
    )
    rows = motion_rows(40, 0)
    model = build_model(config, [rows] + [motion_rows(40, s) for s in range(1, 4)], seed=0)
    with torch.no_grad():
        x = model.prepare(torch.linspace(0, 1, 40), torch.from_numpy(rows), model.obs_columns)  # (40, 1 + 8)
        enc = model.encoder(model.embed_time(x))  # (40, H)
        high = torch.from_numpy(rows[:, 0] > 0)
        r_high, r_low = enc[high].mean(0), enc[~high].mean(0)  # (H,) each
        direction = (r_high - r_low) / (r_high - r_low).norm() ** 2  # unit logit change from one region to the other
        model.gate.weight.copy_(torch.tensor([[8.0], [-8.0], [0.0]]) * direction)  # (d, H)
        model.gate.bias.copy_(-model.gate.weight @ (r_high + r_low) / 2)
    return save_checkpoint(model, directory, extra)


@pytest.fixture
def checkpoint(tmp_path) -> Path:
    return make_checkpoint(tmp_path / "ckpt")


def chunks(path: Path, entity: str, recording: int = 0) -> list:
    from rerun.chunk import RrdReader

    reader = RrdReader(path)
    store = reader.recordings()[recording]
    return [c for c in reader.stream(store=store).to_chunks() if c.entity_path == entity]


def column(path: Path, entity: str, name: str, recording: int = 0, static: bool = False) -> tuple[list, list]:
    """(frame indices, values) of one component over all non-static chunks of `entity`, sorted by frame."""
    rows = []
    for c in chunks(path, entity, recording):
        if c.is_static != static:
            continue
        batch = c.to_record_batch()
        frames = batch.column(L.TIMELINE_FRAME).to_pylist() if not static else [None] * batch.num_rows
        rows += zip(frames, batch.column(name).to_pylist())
    rows.sort(key=lambda r: -1 if r[0] is None else r[0])
    return [r[0] for r in rows], [r[1] for r in rows]


def rrd_verify(path: Path) -> subprocess.CompletedProcess:
    exe = str(RERUN) if RERUN.exists() else shutil.which("rerun")
    return subprocess.run([exe, "rrd", "verify", str(path)], capture_output=True, text=True, timeout=120)


def test_the_rrd_holds_one_gate_row_per_step_and_switches_at_argmax_changes(tmp_path, checkpoint):
    traj = trajectory(steps=40)
    rec = write_trajectory(tmp_path / "ep.mcap", traj)
    argmax_policy = ConditioningPolicy(switch_margin=0.0)  # the active expert is the argmax at every step
    (out,) = replay(checkpoint, [rec], tmp_path / "out" / "replay.rrd", policy=argmax_policy, connect=None, quiet=True)
    assert out == tmp_path / "out" / "replay.rrd" and out.exists()
    assert sorted(p.name for p in out.parent.iterdir()) == [
        RECORD_FILE,
        "replay.experts.json",
        "replay.rrd",
    ]  # no temporaries left

    frames, gates = column(out, L.GATES, "Scalars:scalars")
    assert frames == list(range(40))
    gates = np.array(gates)  # (T, d)
    assert gates.shape == (40, N_EXPERTS)
    np.testing.assert_allclose(gates.sum(1), 1.0, atol=1e-6)
    argmax = gates.argmax(1)
    changes = (np.flatnonzero(argmax[1:] != argmax[:-1]) + 1).tolist()
    assert len(changes) >= 2, "the test data should make the gate switch"

    log_frames, texts = column(out, L.SWITCH_LOG, "TextLog:text")
    assert log_frames == [0] + changes
    assert texts[0][0].startswith("step 0 (0.00 s): first read ")
    for k, (text,) in zip(changes, texts[1:]):
        assert text.startswith(f"step {k} ") and f"expert {argmax[k - 1]} -> expert {argmax[k]}" in text
    # the lane shows the active expert, or "unsure" where it holds less than SURE_GATE, from each change of that on
    unsure = gates.max(1) < SURE_GATE
    assert 0 < unsure.sum() < 40, "the test data should make the gate unsure at some steps, sure at others"
    shown = [L.UNSURE if unsure[k] else f"expert {argmax[k]}" for k in range(40)]
    state_frames, states = column(out, L.ACTIVE_EXPERT, "StateChange:state")
    assert state_frames == [k for k in range(40) if k == 0 or shown[k] != shown[k - 1]]
    assert states == [[shown[k]] for k in state_frames]

    image_frames, blobs = column(out, L.CAMERA, "EncodedImage:blob")
    assert image_frames == list(range(40))
    assert [bytes(b[0]) for b in blobs] == traj.frames  # the stored JPEG bytes, not re-encoded
    ee_frames, translations = column(out, L.EE, "Transform3D:translation")
    assert ee_frames == list(range(40))
    np.testing.assert_allclose(np.array(translations).reshape(40, 3), traj.pose[:, :3], atol=1e-6)
    pred_frames, strips = column(out, L.PREDICTION, "LineStrips3D:strips")
    assert pred_frames == list(range(40)) and len(strips[0][0]) > 1
    _, colors = column(out, L.PREDICTION, "LineStrips3D:colors")  # the active expert's colour, packed RGBA
    packed = [(r << 24) | (g << 16) | (b << 8) | 255 for r, g, b in [*L.expert_colors(N_EXPERTS), L.UNSURE_COLOR]]
    assert [c[0] for c in colors] == [packed[-1] if u else packed[e] for e, u in zip(argmax, unsure)]
    time_rows = [
        c.to_record_batch().column(L.TIMELINE_TIME).to_pylist() for c in chunks(out, L.GATES) if not c.is_static
    ]
    assert sorted(t for rows in time_rows for t in rows)[:2] == [dt.timedelta(0), dt.timedelta(seconds=0.1)]
    _, names = column(out, L.GATES, "SeriesLines:names", static=True)
    assert names == [[f"expert {e}" for e in range(N_EXPERTS)]]

    decisions = read_decisions(out)["recordings"]
    assert len(decisions) == 1
    assert decisions[0]["experts"] == argmax.tolist()
    assert [s["step"] for s in decisions[0]["switches"]] == changes
    np.testing.assert_allclose(decisions[0]["gates"], gates, atol=1e-5)
    assert rrd_verify(out).returncode == 0, rrd_verify(out).stderr


def test_the_default_policy_keeps_its_expert_unless_the_leader_leads_by_the_margin_or_it_fell(tmp_path, checkpoint):
    rec = write_trajectory(tmp_path / "ep.mcap", trajectory(steps=40))
    (out,) = replay(checkpoint, [rec], tmp_path / "kept.rrd", connect=None, quiet=True)
    (plain,) = replay(checkpoint, [rec], tmp_path / "argmax.rrd", policy=ConditioningPolicy(switch_margin=0.0),
                      connect=None, quiet=True)  # fmt: skip
    kept, argmax = read_decisions(out)["recordings"][0], read_decisions(plain)["recordings"][0]
    gates, experts = np.array(kept["gates"]), np.array(kept["experts"])
    policy = ConditioningPolicy()
    np.testing.assert_allclose(gates, argmax["gates"])  # the rule changes the active expert, never the gate
    assert experts[0] == gates[0].argmax() and len(kept["switches"]) <= len(argmax["switches"])
    assert [s["step"] for s in kept["switches"]] == (np.flatnonzero(experts[1:] != experts[:-1]) + 1).tolist()
    for k in range(1, 40):
        lead = gates[k].max() - gates[k, experts[k - 1]]
        fell = k >= policy.switch_window and gates[k - policy.switch_window, experts[k - 1]] - gates[k, experts[k - 1]]
        moved = lead >= policy.switch_margin or fell >= policy.switch_margin
        assert experts[k] == (gates[k].argmax() if moved else experts[k - 1]), k


def test_several_recordings_become_one_file_each_in_the_order_given(tmp_path, checkpoint):
    """A file of one recording opens on it in the viewer (a merged file opens on one of them, which is not fixed)."""
    from rerun.chunk import RrdReader

    (tmp_path / "traj").mkdir()
    paths = [
        write_trajectory(tmp_path / "traj" / f"ep{i}.mcap", trajectory(steps=20 + 10 * i, seed=i, name=f"ep{i}"))
        for i in (1, 0)
    ]
    files = replay(checkpoint, paths, tmp_path / "both.rrd", connect=None, quiet=True)
    assert files == [tmp_path / "both-01-traj-ep1.rrd", tmp_path / "both-02-traj-ep0.rrd"]
    assert not (tmp_path / "both.rrd").exists() and not list(tmp_path.glob(".both*"))
    for file, steps in zip(files, (30, 20)):
        assert len(RrdReader(file).recordings()) == 1
        assert len(column(file, L.GATES, "Scalars:scalars")[0]) == steps
        assert rrd_verify(file).returncode == 0
    record = read_decisions(tmp_path / "both.rrd")
    assert [r["n_steps"] for r in record["recordings"]] == [30, 20] and record["n_experts"] == N_EXPERTS
    assert [r["rrd"] for r in record["recordings"]] == [f.name for f in files] == record["rrd"]


def test_merge_puts_every_recording_into_one_file_in_the_order_given(tmp_path, checkpoint):
    from rerun.chunk import RrdReader

    paths = [
        write_trajectory(tmp_path / f"ep{i}.mcap", trajectory(steps=20 + 10 * i, seed=i, name=f"ep{i}")) for i in (1, 0)
    ]
    (out,) = replay(checkpoint, paths, tmp_path / "both.rrd", connect=None, merge=True, quiet=True)
    assert out == tmp_path / "both.rrd"
    assert [r.recording_id.split("-")[1] for r in RrdReader(out).recordings()] == ["ep1", "ep0"]
    for i, steps in enumerate((30, 20)):
        assert len(column(out, L.GATES, "Scalars:scalars", recording=i)[0]) == steps
    assert rrd_verify(out).returncode == 0
    assert not list(tmp_path.glob(".both.rrd*"))


IDENTITY = {"architecture": "mobilenet_v2", "weights": "random", "weights_sha256": "a" * 64}


def make_feature_checkpoint(directory: Path, extractor: dict) -> Path:
    """An untrained 1288-column model (observes features, pose, gripper) trained on features of `extractor`."""
    columns = ColumnRoles(width=STEP_DIM, observed=((0, STEP_DIM),), predicted=((1280, STEP_DIM),))
    config = CNEPConfig(columns=columns, n_experts=2, encoder_widths=(8,), expert_widths=(8,), time_frequencies=2)
    model = build_model(config, [trajectory(width=STEP_DIM, seed=s).data for s in range(3)], seed=0)
    blocks = {name: list(span) for name, span in BLOCKS_FULL.items()}
    return save_checkpoint(
        model,
        directory,
        {"layout": {"recording_width": STEP_DIM, "columns": [[0, STEP_DIM]], "blocks": blocks}, "extractor": extractor},
    )


def test_a_recording_without_the_blocks_the_checkpoint_needs_is_refused_before_anything_is_written(tmp_path):
    ckpt = make_feature_checkpoint(tmp_path / "ckpt", IDENTITY)
    rec = write_trajectory(tmp_path / "narrow.mcap", trajectory())
    with pytest.raises(
        PipelineError,
        match=r"narrow.mcap: the recording has 8 columns .* 1288-column trajectories "
        r"and needs features",
    ):
        replay(ckpt, [rec], tmp_path / "x.rrd", connect=None, quiet=True)
    assert not (tmp_path / "x.rrd").exists() and not decisions_path(tmp_path / "x.rrd").exists()


def test_a_recording_from_another_extractor_is_refused_naming_both(tmp_path):
    """Like training: features of other weights (another sha256) would silently move the gate."""
    ckpt = make_feature_checkpoint(tmp_path / "ckpt", IDENTITY)
    same = write_trajectory(tmp_path / "same.mcap", trajectory(width=STEP_DIM, extractor=IDENTITY))
    assert replay(ckpt, [same], tmp_path / "ok.rrd", connect=None, quiet=True) == [tmp_path / "ok.rrd"]
    other = write_trajectory(
        tmp_path / "other.mcap", trajectory(width=STEP_DIM, extractor={**IDENTITY, "weights_sha256": "b" * 64})
    )
    with pytest.raises(
        PipelineError,
        match=r"different feature extractors.*sha256 aaaaaaaaaaaa.*ckpt/config.json.*"
        r"sha256 bbbbbbbbbbbb.*other.mcap",
    ):
        replay(ckpt, [same, other], tmp_path / "x.rrd", connect=None, quiet=True)
    assert not list(tmp_path.glob("x.*")) and not list(tmp_path.glob(".x.*"))


def test_a_checkpoint_whose_extractor_was_edited_is_refused(tmp_path, capsys):
    ckpt = make_feature_checkpoint(tmp_path / "ckpt", IDENTITY)
    config = ckpt / "config.json"
    config.write_text(config.read_text().replace("a" * 64, "0" * 64))
    rec = write_trajectory(
        tmp_path / "rec.mcap", trajectory(width=STEP_DIM, extractor={**IDENTITY, "weights_sha256": "0" * 64})
    )
    assert main(["replay", str(ckpt), str(rec), "--out", str(tmp_path / "x.rrd"), "--no-live"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "config.json: the checkpoint config does not match its checksum" in err


def test_a_motion_checkpoint_replays_8_and_1288_column_recordings_alike(tmp_path):
    """The motion columns are found by the recording's layout, whatever width the checkpoint was trained on."""
    layout = {
        "recording_width": STEP_DIM,
        "columns": [[1280, 1288]],
        "blocks": {name: list(span) for name, span in BLOCKS_MOTION.items()},
    }
    from_wide = make_checkpoint(tmp_path / "ckpt", extra={"layout": layout})
    from_narrow = make_checkpoint(tmp_path / "plain")  # no layout entry: the model's own 8 columns
    wide = write_trajectory(tmp_path / "wide.mcap", trajectory(width=STEP_DIM))
    narrow = write_trajectory(tmp_path / "n.mcap", trajectory())
    gates = [
        read_decisions(replay(ckpt, [rec], tmp_path / f"{i}.rrd", connect=None, quiet=True)[0])["recordings"][0][
            "gates"
        ]
        for i, (ckpt, rec) in enumerate(
            [(from_wide, wide), (from_wide, narrow), (from_narrow, wide), (from_narrow, narrow)]
        )
    ]
    assert all(g == gates[0] for g in gates[1:])


def test_decisions_go_into_a_copy_of_the_recording_as_events(tmp_path, checkpoint):
    rec = write_trajectory(tmp_path / "ep.mcap", trajectory(steps=40))
    before = rec.read_bytes()
    (out,) = replay(checkpoint, [rec], tmp_path / "r.rrd", connect=None, events_dir=tmp_path / "events", quiet=True)
    assert rec.read_bytes() == before
    events = read_events(tmp_path / "events" / "ep.mcap")
    decisions = read_decisions(out)["recordings"][0]
    assert len(events) == 1 + len(decisions["switches"])
    assert [int(e.metadata["step"]) for e in events] == [0] + [s["step"] for s in decisions["switches"]]
    assert [int(e.metadata["expert"]) for e in events] == [
        decisions["experts"][int(e.metadata["step"])] for e in events
    ]
    ts = 1_700_000_000_000_000_000 + np.arange(40) * 100_000_000
    assert sum(e.duration_ns for e in events) == ts[-1] - ts[0]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_no_viewer_means_a_warning_and_the_file(tmp_path, checkpoint, caplog):
    rec = write_trajectory(tmp_path / "ep.mcap", trajectory(steps=10, frames=False))
    url = f"rerun+http://127.0.0.1:{free_port()}/proxy"
    with caplog.at_level(logging.WARNING, logger="cnep.pipeline.replay.stage"):
        (out,) = replay(checkpoint, [rec], tmp_path / "r.rrd", connect=url, quiet=True)
    assert "no Rerun viewer answers" in caplog.text
    assert column(out, L.CAMERA, "EncodedImage:blob") == ([], [])  # motion-only: no camera entity
    assert len(column(out, L.GATES, "Scalars:scalars")[0]) == 10


def gate_rows_received(path: Path) -> int:
    """Gate rows in an .rrd that a receiving viewer is still writing (0 until it has a readable recording)."""
    from rerun.chunk import RrdReader

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # no footer yet: the viewer is still writing
            chunks = RrdReader(path).stream().to_chunks()
    except (RuntimeError, ValueError):
        return 0
    return sum(c.num_rows for c in chunks if c.entity_path == L.GATES and not c.is_static)


def test_a_reachable_viewer_receives_the_live_stream_and_the_file_is_still_complete(tmp_path, checkpoint, caplog):
    """A headless `rerun` that saves what it receives stands in for the viewer."""
    import rerun_cli

    port, received = free_port(), tmp_path / "received.rrd"
    exe = Path(rerun_cli.__file__).parent / "rerun"  # the binary itself (the `rerun` script would fork it)
    viewer = subprocess.Popen(
        [str(exe), "--port", str(port), "--save", str(received)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    try:
        url = f"rerun+http://127.0.0.1:{port}/proxy"
        deadline = time.monotonic() + 20
        while not viewer_reachable(url) and time.monotonic() < deadline:
            time.sleep(0.1)
        rec = write_trajectory(tmp_path / "ep.mcap", trajectory(steps=15))
        with caplog.at_level(logging.INFO, logger="cnep.pipeline.replay.stage"):
            (out,) = replay(checkpoint, [rec], tmp_path / "r.rrd", connect=url, quiet=True)
        assert f"streaming live to {url}" in caplog.text
        while gate_rows_received(received) < 15 and time.monotonic() < deadline:
            time.sleep(0.2)
        assert gate_rows_received(received) == 15
    finally:
        viewer.terminate()
        viewer.wait(timeout=20)
    assert len(column(out, L.GATES, "Scalars:scalars")[0]) == 15
    assert rrd_verify(out).returncode == 0


def test_serve_hosts_a_server_that_replay_streams_to(tmp_path, checkpoint, caplog):
    server, url = serve(free_port())
    try:
        assert viewer_reachable(url)
        rec = write_trajectory(tmp_path / "ep.mcap", trajectory(steps=15))
        with caplog.at_level(logging.INFO, logger="cnep.pipeline.replay.stage"):
            (out,) = replay(checkpoint, [rec], tmp_path / "r.rrd", connect=url, quiet=True)
        assert "streaming live" in caplog.text
    finally:
        server.disconnect()
    assert len(column(out, L.GATES, "Scalars:scalars")[0]) == 15


def test_cli_replay_prints_the_expert_of_each_recording(tmp_path, checkpoint, capsys):
    rec = write_trajectory(tmp_path / "ep.mcap", trajectory(steps=20))
    code = main(
        [
            "-q",
            "replay",
            str(checkpoint),
            str(rec),
            "--out",
            str(tmp_path / "c.rrd"),
            "--no-live",
            "--window",
            "3",
            "--anchors",
            "0",
            "--switch-margin",
            "0.25",
        ]
    )
    assert code == 0
    printed = capsys.readouterr().out
    majority = read_decisions(tmp_path / "c.rrd")["recordings"][0]["majority_expert"]
    assert f"ep.mcap: expert {majority} " in printed and "c.experts.json" in printed
    policy = {"window": 3, "anchors": 0, "first_expert": "argmax", "switch_margin": 0.25, "switch_window": 3}
    assert read_decisions(tmp_path / "c.rrd")["policy"] == policy


def test_cli_replay_reports_a_misfit_as_one_line(tmp_path, capsys):
    rec = write_trajectory(tmp_path / "narrow.mcap", trajectory())
    ckpt = make_feature_checkpoint(tmp_path / "ckpt", IDENTITY)
    assert main(["replay", str(ckpt), str(rec), "--out", str(tmp_path / "c.rrd"), "--no-live"]) == 2
    assert "8 columns" in capsys.readouterr().err


@pytest.mark.parametrize("d", [1, 2, 5, 12])
def test_the_blueprint_is_built_from_the_number_of_experts(d):
    blueprint = L.blueprint(d)
    assert blueprint is not None
    assert len(set(L.expert_colors(d))) == min(d, len(L.PALETTE))


def test_a_one_step_recording_is_refused(tmp_path, checkpoint):
    rec = write_trajectory(tmp_path / "one.mcap", trajectory(steps=1))
    with pytest.raises(PipelineError, match="one.mcap: 1 step"):
        replay(checkpoint, [rec], tmp_path / "x.rrd", connect=None, quiet=True)


def test_event_copies_that_would_overwrite_each_other_are_refused(tmp_path, checkpoint):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    paths = [write_trajectory(tmp_path / d / "ep.mcap", trajectory(steps=10)) for d in ("a", "b")]
    with pytest.raises(PipelineError, match="named alike"):
        replay(checkpoint, paths, tmp_path / "x.rrd", connect=None, events_dir=tmp_path / "ev", quiet=True)


def test_a_feature_checkpoint_that_names_no_extractor_is_refused(tmp_path):
    ckpt = make_feature_checkpoint(tmp_path / "ckpt", {})
    rec = write_trajectory(tmp_path / "rec.mcap", trajectory(width=STEP_DIM, extractor=IDENTITY))
    with pytest.raises(
        PipelineError,
        match=r"ckpt/config.json: the model sees image features but the checkpoint "
        r"names no feature extractor",
    ):
        replay(ckpt, [rec], tmp_path / "x.rrd", connect=None, quiet=True)


def test_the_first_read_says_when_the_gate_is_unsure_and_between_which_experts():
    sure = first_read_text(np.array([0.02, 0.95, 0.03, 0.0]), sure=True)
    assert sure == "step 0 (0.00 s): first read expert 1 (p = 0.95)"
    unsure = first_read_text(np.array([0.05, 0.28, 0.0, 0.67]), sure=False)
    assert unsure == "step 0 (0.00 s): first read unsure (expert 3 0.67, expert 1 0.28)"
