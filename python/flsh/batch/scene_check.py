"""flsh's own checks of every generated scene (flsh.load_scene_file: keys, types, ranges, files),
run before anything is written; a failure is reported as a SpecError at the spec key the
faulty value came from. What only building or running finds (a corrupt motion file, too many
betas for the model) fails that job at run time instead, and the others go on."""
import json
import re
import tempfile
from pathlib import Path

from .checks import child

_PARTS = re.compile(r"(?=[.\[])")  # "avatars[0].options.x" -> avatars, [0], .options, .x


def spec_key(job, scene_key):
    """The spec key path of a key path of `job`'s scene (its longest known prefix, job.origin,
    followed by the rest)."""
    parts = _PARTS.split(scene_key)
    for n in range(len(parts), 0, -1):
        prefix = "".join(parts[:n])
        if prefix in job.origin:
            return job.origin[prefix] + "".join(parts[n:])
    return child(job.origin[""], scene_key)


def check_scenes(reader, jobs):
    """Parses each job's scene as `flsh simulate` would; raises SpecError on the first
    problem, naming the spec key and the job."""
    import flsh

    seen = set()
    with tempfile.TemporaryDirectory(prefix="flsh-batch-check-") as folder:
        path = Path(folder) / "scene.json"
        for job in jobs:
            text = json.dumps(job.scene)
            if text in seen:
                continue
            seen.add(text)
            path.write_text(text)
            try:
                flsh.load_scene_file(str(path))
            except (ValueError, OSError) as error:
                message = str(error)
                prefix = f"{path}: "
                if not message.startswith(prefix):
                    reader.fail(job.origin["id"], f"job '{job.id}': {message}")
                scene_key, _, what = message[len(prefix):].partition(": ")
                reader.fail(spec_key(job, scene_key), f"{what} (job '{job.id}')")
