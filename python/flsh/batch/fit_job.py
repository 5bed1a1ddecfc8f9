"""One fitting job (spec "fits"), run where Dask puts it: the subject's scene, its scans, the fit
(flsh.fitting.fit_scans on flsh.torch.RolloutSimulator.from_scene) and its outputs, written into
a hidden temporary folder renamed into place at the end, as simulation jobs are (job.py).

    fit.json            the fitted unknowns (start, fit; per material entry its factor), the
                        fitted β, losses, RMS distances, L-BFGS iterations, timings
    material.json       the fitted material file (soft models)
    fitted_scene.json   the scene with the fitted β and material: `flsh simulate` runs it
    fitted.npz          times (T,), vertices (T, V, 3) of the fitted simulation (steps 1..T),
                        betas (K,), faces (F, 3)
    scene.json, log.txt, job.json as for simulation jobs"""
import json
from pathlib import Path

import numpy as np

from .job import output_to, run_in_folder

FIT_OUTPUTS = ("fit.json", "fitted.npz", "fitted_scene.json", "material.json")


def fitted_scene(scene, betas, soft):
    """The job's scene with the fitted shape (and material file, for soft models), as a scene
    file in the job's folder ("materials" relative to it)."""
    scene = json.loads(json.dumps(scene))
    avatar = scene["avatars"][0]
    avatar["betas"] = [float(b) for b in betas]
    if soft:
        avatar["materials"] = "material.json"
    scene.pop("outputs", None)  # flsh simulate's default outputs
    return scene


def run_fit_job(job, out_dir):
    """Runs the fitting job `job` into OUT_DIR/jobs/JOB_ID and returns its manifest record;
    never raises for a failing job (its record says "failed" and why)."""
    return run_in_folder(job, out_dir, fit_into)


def fit_into(job, temp, record):
    """A fitting job's work in its temporary folder `temp` (scene.json written): the fit and
    its outputs; fills `record`."""
    import flsh.fitting  # noqa: PLC0415 (imports torch: only where fits run)
    import flsh.torch  # noqa: PLC0415

    settings = job.fit
    with output_to(temp / "log.txt"):
        simulator = flsh.torch.RolloutSimulator.from_scene(str(temp / "scene.json"),
                                                           verbose=True)
        scans = flsh.fitting.load_scans(settings["scans"], simulator)
        result = flsh.fitting.fit_scans(
            simulator, scans, betas=settings["betas"], material=settings["material"],
            iterations=settings["iterations"], noise=settings["noise"], log=print)
    soft = result.material is not None
    if soft:
        result.save_material(temp / "material.json")
    h = simulator.options.time_step
    np.savez(temp / "fitted.npz", times=h * np.arange(1, simulator.steps + 1),
             vertices=result.vertices.astype(job.data_dtype), betas=result.betas,
             faces=np.asarray(simulator.body.faces, dtype=np.int32))
    (temp / "fitted_scene.json").write_text(
        json.dumps(fitted_scene(job.scene, result.betas, soft), indent=1) + "\n")
    figures = result.summary()
    figures.update(scans=settings["scans"], scan_kind=scans.kind, scan_frames=scans.num_frames,
                   skipped_start_frames=scans.skipped, steps=simulator.steps, time_step=h)
    (temp / "fit.json").write_text(json.dumps(figures, indent=1) + "\n")
    folder = f"jobs/{job.id}"
    written = [name for name in FIT_OUTPUTS if (temp / name).exists()]
    record.update(
        steps=simulator.steps, scan_frames=scans.num_frames,
        start_rms_mm=figures["start_rms_mm"], final_rms_mm=figures["final_rms_mm"],
        iterations=result.iterations, evaluations=result.evaluations,
        fit_seconds=result.seconds, betas=figures["betas"],
        outputs={"folder": folder, "scene": f"{folder}/scene.json", "log": f"{folder}/log.txt",
                 **{Path(n).stem: f"{folder}/{n}" for n in written}})
