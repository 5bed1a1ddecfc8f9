"""The progress line (counts and ETA, on stderr) and the summary table of a batch run."""
import sys
import time
from dataclasses import dataclass


def clock(seconds):
    """Seconds as H:MM:SS."""
    seconds = int(round(seconds))
    return f"{seconds // 3600}:{seconds // 60 % 60:02d}:{seconds % 60:02d}"


@dataclass
class Summary:
    """What a run did. jobs_per_minute counts the jobs run (done or failed) over the time from
    submitting the first to the last one finishing."""
    done: int
    failed: int
    skipped: int
    not_run: int
    seconds: float
    workers: int

    @property
    def jobs_per_minute(self):
        run = self.done + self.failed
        return 60.0 * run / self.seconds if run and self.seconds > 0 else 0.0

    def table(self):
        rows = [("done", self.done), ("failed", self.failed),
                ("skipped (done before)", self.skipped)]
        if self.not_run:
            rows.append(("not run (interrupted)", self.not_run))
        rows.append(("total", self.done + self.failed + self.skipped + self.not_run))
        lines = ["flsh.batch summary:", f"  {'jobs':<22}{'count':>6}"]
        lines += [f"  {name:<22}{count:>6}" for name, count in rows]
        lines.append(f"  {self.done + self.failed} job(s) run in {self.seconds:.1f} s on "
                     f"{self.workers} worker(s): {self.jobs_per_minute:.1f} jobs/min")
        return "\n".join(lines)


class Progress:
    """Counts finished jobs and prints the progress line: rewritten in place on a terminal,
    one line per finished job otherwise."""

    def __init__(self, to_run, skipped, workers, stream=None):
        self.to_run, self.skipped, self.workers = to_run, skipped, workers
        self.stream = stream or sys.stderr
        self.done = self.failed = 0
        self.start = time.perf_counter()
        self.tty = getattr(self.stream, "isatty", lambda: False)()

    def write(self, text, rewrite=False):
        """Prints a line; on a terminal, a `rewrite` line is overwritten by the next one."""
        if self.tty:
            self.stream.write("\r\033[K" + text + ("" if rewrite else "\n"))
        else:
            self.stream.write(text + "\n")
        self.stream.flush()

    def header(self, out_dir):
        self.write(f"flsh.batch: {self.to_run + self.skipped} job(s): {self.to_run} to run, "
                   f"{self.skipped} done before (skipped); {self.workers} worker(s); "
                   f"output {out_dir}")

    def line(self):
        finished = self.done + self.failed
        elapsed = time.perf_counter() - self.start
        remaining = self.to_run - finished
        eta = (clock(elapsed / finished * remaining) if finished and remaining
               else "0:00:00" if not remaining else "?")
        return (f"flsh.batch: {finished}/{self.to_run} finished ({self.done} done, "
                f"{self.failed} failed), {self.skipped} skipped, {clock(elapsed)} elapsed, "
                f"ETA {eta}")

    def finished(self, record):
        """Counts one finished job (its manifest record) and prints the line."""
        if record["status"] == "done":
            self.done += 1
        else:
            self.failed += 1
            first_line = (record.get("error") or "").splitlines()[:1] or [""]
            self.write(f"flsh.batch: job '{record['job']}' failed: {first_line[0]}")
        self.write(self.line(), rewrite=True)

    def summary(self):
        if self.tty:
            self.stream.write("\n")
        return Summary(self.done, self.failed, self.skipped,
                       self.to_run - self.done - self.failed,
                       time.perf_counter() - self.start, self.workers)
