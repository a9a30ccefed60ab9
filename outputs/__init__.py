"""How every cnep output is written: one run at a time per output, under temporary names, renamed when complete, and
replaced or deleted only by the command that recorded writing it.

    with writing_as("ingest"), output_lock(out_folder, folder=True):  # the command; the run's exclusive lock
        with output_file(out_folder / "a.mcap") as tmp:                # `.a.mcap.<pid>-<random>.tmp`, renamed
            write_demonstration(tmp, demo)                              # and recorded when complete

Every package writes its files through `atomic_file` / `write_atomically` / `staged`; the pipeline's stages say which
command they are (`writing_as`), hold `output_lock` on their outputs for the whole run, which also removes the
temporary files that killed runs left there, and write their outputs through `output_file` / `write_output` /
`staged(record=True)`, which name them in the record of their folder as that command's (cnep.outputs.record) and
replace only that command's recorded files. A folder output is replaced as a whole by `publish_folder`, and emptied
by `remove_owned` (cnep.outputs.folders). This package imports no other part of cnep, so all of them may import it.
"""

from cnep.outputs.atomic import (
    TEMPORARY,
    Staging,
    atomic_file,
    is_stale_temporary,
    naming,
    output_file,
    pid_alive,
    remove_stale_temporaries,
    signals_held,
    staged,
    temporary_path,
    write_atomically,
    write_output,
)
from cnep.outputs.errors import OutputError
from cnep.outputs.folders import NotOwned, discard, publish_folder, recover_set_aside, remove_owned, set_aside
from cnep.outputs.lock import FOLDER_LOCK, is_cnep_lock, is_lock_name, lock_path, output_lock, remove_stale_locks
from cnep.outputs.record import (
    RECORD_FILE,
    WRITER_ENV,
    Owns,
    foreign_files,
    is_bookkeeping,
    is_recorded,
    read_record,
    record_written,
    recorded_by,
    writer,
    writing_as,
)

__all__ = [
    "FOLDER_LOCK",
    "TEMPORARY",
    "NotOwned",
    "OutputError",
    "Owns",
    "RECORD_FILE",
    "Staging",
    "WRITER_ENV",
    "atomic_file",
    "discard",
    "foreign_files",
    "is_bookkeeping",
    "is_cnep_lock",
    "is_lock_name",
    "is_recorded",
    "is_stale_temporary",
    "lock_path",
    "naming",
    "output_file",
    "output_lock",
    "pid_alive",
    "publish_folder",
    "read_record",
    "record_written",
    "recorded_by",
    "recover_set_aside",
    "remove_owned",
    "remove_stale_locks",
    "remove_stale_temporaries",
    "set_aside",
    "signals_held",
    "staged",
    "temporary_path",
    "write_atomically",
    "write_output",
    "writer",
    "writing_as",
]
