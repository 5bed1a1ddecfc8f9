"""manifest.jsonl: one JSON line per finished job (done or failed), appended by the client
process only, each line flushed and fsync'ed as the job finishes. A job's latest line is its
status; a re-run skips the jobs whose latest line is "done" with the same spec hash and flsh
version and whose folder holds the same job.json."""
import json
import os
from pathlib import Path

MANIFEST_NAME = "manifest.jsonl"


class Manifest:
    """The manifest file of one output folder, open for appending."""

    def __init__(self, out_dir):
        self.path = Path(out_dir) / MANIFEST_NAME
        self._file = open(self.path, "a", encoding="utf-8")

    def append(self, record):
        """Writes `record` as one line, on disk before this returns."""
        self._file.write(json.dumps(record, sort_keys=True) + "\n")
        self._file.flush()
        os.fsync(self._file.fileno())

    def close(self):
        self._file.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def latest_records(out_dir):
    """{job id: its latest manifest record} of the output folder `out_dir` ({} without a
    manifest). A line that is not JSON (a line cut short by a crash) is ignored."""
    path = Path(out_dir) / MANIFEST_NAME
    records = {}
    if not path.is_file():
        return records
    with open(path, encoding="utf-8") as f:
        for line in f:
            try:
                record = json.loads(line)
            except json.JSONDecodeError:
                continue
            if isinstance(record, dict) and isinstance(record.get("job"), str):
                records[record["job"]] = record
    return records


def folder_record(out_dir, job_id):
    """The record in the job.json of job `job_id`'s folder (None if there is none): a folder
    appears only once complete, so its job.json is as good as a manifest line."""
    try:
        with open(Path(out_dir) / "jobs" / job_id / "job.json", encoding="utf-8") as f:
            record = json.load(f)
    except (OSError, ValueError):
        return None
    return record if isinstance(record, dict) else None


def is_done(job, record, version):
    """True when `record` (a job.json's) shows `job` done with its spec hash and flsh
    `version`: the job need not run again."""
    return (record is not None and record.get("status") == "done"
            and record.get("spec_hash") == job.spec_hash
            and record.get("flsh_version") == version)
