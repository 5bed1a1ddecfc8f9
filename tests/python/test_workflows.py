"""Short versions of the PyTorch workflows in examples/python on synthetic ground truth:
workflow 2 (train_physics_loss.py: a network trained through the simulator with a physics loss)
and workflow 3 (recover_jump.py: β and the take-off velocity of a simulated jump recovered from
its joint trajectory); and that the scripts run (also workflow 4, fit_soft_tissue.py, with the
ROM's default handle basis and with modes, whose fit is tested in test_fit_material.py)."""
import subprocess
import sys
from pathlib import Path

import numpy as np

EXAMPLES = Path(__file__).resolve().parents[2] / "examples" / "python"


def test_workflow2_physics_loss_goes_down(example):
    train = example("train_physics_loss").train
    losses, _ = train(vertices=600, steps=6, sequences=2, epochs=60, validation=0,
                      log=lambda _: None)
    assert losses[0] > 1e-2, losses  # the unknown arm swings are visible in the joints
    assert losses[-1] < 0.2 * losses[0], losses  # measured: 0.05


def test_workflow3_recovers_shape_and_take_off_velocity(example):
    recover = example("recover_jump").recover
    # 30 steps of 1/60 s: take-off, flight and landing (the ground acts on the true jump).
    result = recover(vertices=600, steps=30, iterations=300, seed=1, log=lambda _: None)
    truth, estimate = result["truth"], result["estimate"]
    assert result["landing_contacts"] > 0
    # The truth is far from the start (β = 0, v = ω = 0) and is found from the joints alone to
    # 1e-6 (β), 1e-6 m/s (v) and 1e-6 rad/s (ω); measured errors are ~1e-9.
    assert np.abs(truth["betas"]).max() > 0.3 and np.abs(truth["linear"]).max() > 1.0
    assert result["final_loss"] < 1e-12 * result["initial_loss"], result
    np.testing.assert_allclose(estimate["betas"], truth["betas"], rtol=0, atol=1e-6)
    np.testing.assert_allclose(estimate["linear"], truth["linear"], rtol=0, atol=1e-6)
    np.testing.assert_allclose(estimate["spin"], truth["spin"], rtol=0, atol=1e-6)


def test_workflow_scripts_run(tmp_path):
    for name, args in (("train_physics_loss", ["--steps", "4", "--sequences", "1",
                                               "--epochs", "2", "--validation", "1"]),
                       ("recover_jump", ["--steps", "4", "--iterations", "2"]),
                       ("fit_soft_tissue", ["--vertices", "800", "--steps", "2", "--iterations",
                                            "1", "--loss", "surface", "--cache", str(tmp_path)]),
                       ("fit_soft_tissue", ["--vertices", "800", "--steps", "2", "--iterations",
                                            "1", "--basis", "modes+handles",
                                            "--vibration-modes", "6", "--modal-columns", "24",
                                            "--cache", str(tmp_path)])):
        result = subprocess.run([sys.executable, str(EXAMPLES / f"{name}.py"), *args],
                                capture_output=True, text=True)
        assert result.returncode == 0, result.stderr
        assert "loss" in result.stdout, result.stdout
