"""How every cnep output is written: one run at a time per output, under temporary names, renamed when complete.

    with output_lock(out_folder, folder=True):       # the run's exclusive lock (cnep.outputs.lock)
        with atomic_file(out_folder / "a.mcap") as f:  # `.a.mcap.<pid>-<random>.tmp`, renamed when complete
            f.write(data)

Every package writes its files through `atomic_file` / `write_atomically` / `staged`; the pipeline's
stages hold `output_lock` on their outputs for the whole run, which also removes the temporary files that
killed runs left there, and name what they wrote in the record of its folder (`record_written`, `staged(record=True)`):
what `--force` may replace later. This package imports no other part of cnep, so all of them may import it.
"""

from cnep.outputs.atomic import (
    TEMPORARY,
    Staging,
    atomic_file,
    is_stale_temporary,
    naming,
    pid_alive,
    remove_stale_temporaries,
    staged,
    temporary_path,
    write_atomically,
)
from cnep.outputs.errors import OutputError
from cnep.outputs.lock import FOLDER_LOCK, is_lock_name, lock_path, output_lock, remove_stale_locks
from cnep.outputs.record import RECORD_FILE, is_recorded, read_record, record_written

__all__ = [
    "FOLDER_LOCK",
    "TEMPORARY",
    "OutputError",
    "RECORD_FILE",
    "atomic_file",
    "is_lock_name",
    "is_recorded",
    "is_stale_temporary",
    "lock_path",
    "naming",
    "output_lock",
    "pid_alive",
    "read_record",
    "record_written",
    "Staging",
    "remove_stale_locks",
    "remove_stale_temporaries",
    "staged",
    "temporary_path",
    "write_atomically",
]
