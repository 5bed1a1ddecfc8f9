"""The two errors of flsh.batch that stop a batch before it runs (exit status 2 of the CLI)."""


class SpecError(ValueError):
    """A bad spec file: the message names the file, the key path and what was expected,
    e.g. ``spec.json: grid.motions[2]: matches no file: /data/clips/*.npz``."""

    def __init__(self, source, key, message):
        self.source, self.key, self.message = str(source), key, message
        super().__init__(f"{self.source}: {key}: {message}" if key else f"{self.source}: {message}")


class BatchError(RuntimeError):
    """A batch that cannot start: its output folder is a file or in use by another run, the
    scheduler cannot be reached, a bad option."""
