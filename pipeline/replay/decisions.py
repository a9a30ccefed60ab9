"""The replay's decisions file, `<name>.experts.json` beside the .rrd, and the decisions as recording events.

    read_decisions("out.rrd")["recordings"][0]["experts"]  # (T,) the active expert per step

Per recording: `experts` (T,), `gates` (T, d), `share` (d,), `majority_expert`, `switches`
[{step, timestamp_ns, from, to, gate}] (`summarise`); `decision_events` turns them into one
`recordings.Event` per span of an active expert, for the copies with events.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from cnep.pipeline.errors import PipelineError
from cnep.pipeline.replay.conditioning import Decisions
from cnep.recordings import Event, Trajectory
from cnep.runtime.jsonfile import read_json

DECISIONS_SUFFIX = ".experts.json"


def decisions_path(out_rrd: str | os.PathLike) -> Path:
    """Where `replay` writes the decisions of `out_rrd`: `<stem>.experts.json` beside it."""
    out = Path(out_rrd)
    return out.with_name(out.stem + DECISIONS_SUFFIX)


def read_decisions(out_rrd: str | os.PathLike) -> dict:
    """The decisions `replay` wrote for `out_rrd`: per recording, `experts` (T,), `gates` (T, d), `share`
    (d,), `majority_expert`, `switches` [{step, timestamp_ns, from, to, gate}]."""
    path = decisions_path(out_rrd)
    try:
        return read_json(path)
    except (OSError, ValueError) as exc:
        raise PipelineError(f"{path}: cannot read the replay decisions ({exc}); run `cnep replay` again") from None


def summarise(path: Path, traj: Trajectory, decisions: Decisions) -> dict:
    """The decisions file's entry of one recording (`path`, read as `traj`); probabilities rounded to 6 places."""
    share = decisions.share()
    return {
        "recording": str(path),
        "episode_id": traj.episode.episode_id,
        "n_steps": len(decisions.experts),
        "majority_expert": int(share.argmax()),
        "share": [round(float(s), 6) for s in share],
        "experts": decisions.experts.tolist(),
        "gates": np.round(decisions.gates, 6).tolist(),
        "switches": [
            {
                "step": s.step,
                "timestamp_ns": s.timestamp_ns,
                "from": s.from_expert,
                "to": s.to_expert,
                "gate": np.round(s.gate, 6).tolist(),
            }
            for s in decisions.switches
        ],
    }


def decision_events(traj: Trajectory, decisions: Decisions) -> list[Event]:
    """One Event per span of an active expert: start time, duration to the next switch (or the end)."""
    ts = traj.timestamps_ns
    starts = [0] + [s.step for s in decisions.switches]
    ends = starts[1:] + [len(ts) - 1]
    events = []
    for i, (a, b) in enumerate(zip(starts, ends)):
        meta = {
            "kind": "active_expert",
            "expert": str(decisions.experts[a]),
            "step": str(a),
            "previous": str(decisions.experts[a - 1]) if i else "",
            "gate": ",".join(f"{p:.4f}" for p in decisions.gates[a]),
        }
        events.append(Event(int(ts[a]), meta, duration_ns=int(ts[b] - ts[a])))
    return events
