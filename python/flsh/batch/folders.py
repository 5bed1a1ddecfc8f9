"""Job folders that appear complete or not at all, and the lock of an output folder.

A job writes into a hidden temporary folder beside its folder, `.ID.tmp-HOST-PID-RANDOM`,
and renames it into place when everything is written. A folder that is already there (a
job redone after its spec changed) is first renamed aside to `.ID.old-HOST-PID-RANDOM`,
then deleted; a crash between the two renames leaves the job missing, so the next run
redoes it. Hidden temporary folders are never read, and are deleted at the start of the
next run and at the end of a run that finished every job."""
import errno
import fcntl
import os
import shutil
import socket
import uuid
from contextlib import contextmanager
from pathlib import Path

from .errors import BatchError

LOCK_NAME = ".flsh-batch.lock"


def _suffix():
    return f"{socket.gethostname()}-{os.getpid()}-{uuid.uuid4().hex[:8]}"


def make_temp(jobs_dir, job_id):
    """A new empty hidden folder in `jobs_dir` for job `job_id` to write into."""
    temp = Path(jobs_dir) / f".{job_id}.tmp-{_suffix()}"
    temp.mkdir(parents=True)
    return temp


def is_temp(name):
    """True for the hidden folders of unfinished or replaced job folders."""
    return name.startswith(".") and (".tmp-" in name or ".old-" in name)


def place(temp, final):
    """Renames the finished folder `temp` to `final`, replacing a previous `final`."""
    temp, final = Path(temp), Path(final)
    try:
        os.rename(temp, final)
        return
    except OSError as error:
        if error.errno not in (errno.ENOTEMPTY, errno.EEXIST, errno.ENOTDIR, errno.EISDIR):
            raise
    aside = final.parent / f".{final.name}.old-{_suffix()}"
    os.rename(final, aside)
    os.rename(temp, final)
    shutil.rmtree(aside, ignore_errors=True)


def remove_stale(jobs_dir):
    """Deletes the hidden temporary folders in `jobs_dir` (those of killed or interrupted
    jobs); returns how many."""
    jobs_dir = Path(jobs_dir)
    if not jobs_dir.is_dir():
        return 0
    stale = [p for p in jobs_dir.iterdir() if is_temp(p.name)]
    for path in stale:
        shutil.rmtree(path, ignore_errors=True)
    return len(stale)


@contextmanager
def locked(out_dir):
    """Holds the lock of the output folder `out_dir` (one batch run at a time may write into
    it); BatchError if another run holds it."""
    path = Path(out_dir) / LOCK_NAME
    with open(path, "a") as handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            raise BatchError(f"{out_dir}: another flsh.batch run is writing into this folder "
                             f"(it holds {path}); wait for it to finish") from None
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def check_unlocked(out_dir):
    """BatchError if a run holds the lock of `out_dir` now (checked before starting workers;
    run_batch takes the lock itself)."""
    if (Path(out_dir) / LOCK_NAME).is_file():
        with locked(out_dir):
            pass


def write_text_atomically(path, text):
    """Writes a small text file through a temporary file and a rename."""
    path = Path(path)
    temp = path.parent / f".{path.name}.tmp-{_suffix()}"
    temp.write_text(text)
    os.replace(temp, path)
