"""The summary path (`read_summary`: what extract and train read of every input first) costs bounded memory and time
whatever the file: a decompression bomb where its summary should be is refused without inflating it, in one line and
exit 2 from `cnep extract` and `cnep train`."""

import tracemalloc

import pytest

from cnep.pipeline.cli.main import main
from cnep.recordings import RecordingError, read_summary
from cnep.recordings.constants import KIND_DEMONSTRATION, KIND_TRAJECTORY
from tests.recordings.hostile import BOMB_PLACEMENTS, bombed_cnep_file

DECLARED = 64 << 20  # what the bomb inflates to: the mcap library's readers allocate it whole
SAYS = f"declares {DECLARED} bytes uncompressed, more than the"


@pytest.mark.parametrize("placement", BOMB_PLACEMENTS)
def test_a_bomb_where_the_summary_should_be_is_refused_without_inflating_it(tmp_path, placement):
    path = tmp_path / "bomb.mcap"
    path.write_bytes(bombed_cnep_file(KIND_DEMONSTRATION, placement, DECLARED))
    tracemalloc.start()
    try:
        with pytest.raises(RecordingError, match=f"{path}: corrupt: damaged chunk at byte .*{SAYS}"):
            read_summary(path, KIND_DEMONSTRATION)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 4 << 20, peak  # the file is 10 KB; nothing near the 64 MiB it inflates to


@pytest.mark.parametrize("command", ["extract", "train"])
def test_extract_and_train_refuse_a_bomb_without_a_summary_in_one_line(tmp_path, capsys, command):
    kind = KIND_DEMONSTRATION if command == "extract" else KIND_TRAJECTORY
    paths = [tmp_path / "bomb.mcap", tmp_path / "other.mcap"]  # training takes two files or more
    for path in paths:
        path.write_bytes(bombed_cnep_file(kind, "no summary", DECLARED))
    capsys.readouterr()
    assert main(["-q", command, *map(str, paths), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(paths[0]) in err[0] and SAYS in err[0], err
    assert not (tmp_path / "out").exists()
