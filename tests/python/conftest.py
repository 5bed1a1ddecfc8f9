"""Shared fixtures of the pytest suite of flsh's Python API.

`import flsh` is deliberately unguarded: if the extension module does not import, every test
must fail (a collection error), never be skipped.
"""
import importlib.util
from pathlib import Path

import numpy as np
import pytest

import flsh
from flsh import smpl_torch


@pytest.fixture(scope="session")
def body():
    """A small synthetic body (800 vertices, 1596 triangles), generated once per session."""
    return flsh.make_synthetic_body(vertices=800)


@pytest.fixture(scope="session")
def reference(body):
    """The plain-PyTorch SMPL reference over the same arrays."""
    return smpl_torch.SmplTorch.from_flsh(body)


@pytest.fixture(scope="session")
def walk():
    """The built-in walk, 1 s at 30 fps (read only)."""
    return flsh.make_builtin_motion("walk", seconds=1.0, fps=30.0)


@pytest.fixture
def rng():
    return np.random.default_rng(20240611)



EXAMPLES = Path(__file__).resolve().parents[2] / "examples" / "python"


@pytest.fixture(scope="session")
def example():
    """A loader of the scripts in examples/python as modules: example("recover_jump")."""
    def load(name):
        spec = importlib.util.spec_from_file_location(f"example_{name}", EXAMPLES / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module
    return load
