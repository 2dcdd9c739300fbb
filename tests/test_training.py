"""Smoke runs of a few iterations: the training loops run, checkpoint and resume."""
import numpy as np
import pytest
import torch

from frontend import MagicPoint, train_magicpoint, train_magicwarp
from frontend.training import export_weights


def test_magicpoint_training_runs_and_resumes(tmp_path):
    config = train_magicpoint.TrainConfig(iterations=2, batch=4, validate_every=1, validation_per_category=1)
    figures = train_magicpoint.run(tmp_path, config)
    assert 0 <= figures["map_noisy"] <= 1
    longer = train_magicpoint.TrainConfig(iterations=3, batch=4, validate_every=1, validation_per_category=1)
    train_magicpoint.run(tmp_path, longer)
    assert torch.load(tmp_path / "last.pt", weights_only=False)["step"] == 3
    shipped = export_weights(tmp_path / "last.pt", tmp_path / "weights.pt")
    assert "optimizer" not in shipped and "rng" not in shipped
    detector = MagicPoint.pretrained("S", path=tmp_path / "weights.pt")  # loads like the shipped weights
    assert detector.heatmap(np.zeros((32, 32), np.uint8)).shape == (32, 32)
    (tmp_path / "junk.pt").write_text("junk")
    with pytest.raises(ValueError, match="not a torch checkpoint"):
        export_weights(tmp_path / "junk.pt", tmp_path / "x.pt")


def test_magicwarp_training_runs_and_resumes(tmp_path):
    config = train_magicwarp.TrainConfig(iterations=2, batch=4, validate_every=2)
    figures = train_magicwarp.run(tmp_path, config)
    assert 0 <= figures["score"] <= 100
    state = torch.load(tmp_path / "last.pt", weights_only=False)
    assert state["step"] == 2 and "rng" in state
