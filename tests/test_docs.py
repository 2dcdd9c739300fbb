"""The docs: examples in the public docstrings run as written; the README stays a short reference."""

import doctest
import importlib
import pkgutil

import pytest

import deepslam

PACKAGES = ("deepslam", "deepslam.frontend", "deepslam.backend", "deepslam.inputs", "deepslam.logs", "deepslam.sim")


def _modules_with_examples() -> list[str]:
    names = []
    for package in PACKAGES:
        path = importlib.import_module(package).__path__
        for module in pkgutil.iter_modules(path, f"{package}."):
            spec = importlib.util.find_spec(module.name)
            if spec and spec.origin and spec.origin.endswith(".py") and ">>> " in open(spec.origin).read():
                names.append(module.name)
    return names


MODULES = _modules_with_examples()


def test_the_public_api_has_examples():
    public = ("backend.pipeline", "backend.relpose", "backend.drift", "frontend.magicpoint", "frontend.magicwarp")
    assert {f"deepslam.{name}" for name in (*public, "inputs.timing")} <= set(MODULES)


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples_run(name):
    import torch

    torch.set_num_threads(1)
    failures, tried = doctest.testmod(importlib.import_module(name), optionflags=doctest.NORMALIZE_WHITESPACE)
    assert tried > 0 and failures == 0


def test_packages_export_their_names_lazily():
    import subprocess
    import sys

    code = "import deepslam, deepslam.frontend, sys; deepslam.PipelineConfig; print('torch' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True).stdout.strip() == "False"
    assert {"Pipeline", "PipelineConfig", "DeepslamError"} <= set(dir(deepslam)) and "Pipeline" in deepslam.__all__
    with pytest.raises(AttributeError, match="no attribute"):
        deepslam.nothing_of_that_name  # noqa: B018


def test_the_readme_stays_a_short_reference_and_agrees_with_the_constraints():
    from pathlib import Path

    root = Path(__file__).parent.parent
    readme = (root / "README.md").read_text()
    assert len(readme.splitlines()) <= 200
    assert "same kind of CPU" in readme  # the magic front-end's figures depend on it
    wheel = "--extra-index-url https://download.pytorch.org/whl/cpu"
    assert wheel in " ".join(readme.split()) and wheel in (root / "constraints.txt").read_text()
