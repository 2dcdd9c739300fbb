"""Smoke runs of a few iterations: the training loops run, checkpoint and resume."""

import json
import logging
import os
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from deepslam.frontend import MagicPoint
from deepslam.frontend.config import EXTRACTION_PRESETS, MagicWarpConfig
from deepslam.frontend.magicpoint import MagicPointConfig
from deepslam.frontend.magicwarp import MagicWarpNet
from deepslam.frontend.training import magicpoint as train_magicpoint
from deepslam.frontend.training import magicwarp as train_magicwarp
from deepslam.frontend.training.loop import LoopConfig, export_weights, train
from deepslam.frontend.training.surgery import load_weights


def test_magicpoint_training_runs_and_resumes(tmp_path, caplog):
    config = train_magicpoint.TrainConfig(iterations=2, batch=4, validate_every=1, validation_per_category=1)
    figures = train_magicpoint.run(tmp_path, config)
    assert 0 <= figures["map_noisy"] <= 1
    logger = logging.getLogger("deepslam")
    logger.addHandler(caplog.handler)  # the command's logger may not propagate once main() configured it
    try:
        with caplog.at_level("INFO", logger="deepslam"):
            assert train_magicpoint.run(tmp_path, config) == figures  # done: said so, the figures as they were
    finally:
        logger.removeHandler(caplog.handler)
    assert f"{tmp_path / 'last.pt'} is at step 2 of --iterations 2: nothing to train" in caplog.text
    longer = train_magicpoint.TrainConfig(iterations=3, batch=4, validate_every=1, validation_per_category=1)
    train_magicpoint.run(tmp_path, longer)
    assert torch.load(tmp_path / "last.pt", weights_only=False)["step"] == 3
    history = json.loads((tmp_path / "history.json").read_text())
    assert len(history) == 3 and all(np.isfinite(h["train_loss"]) for h in history)
    assert (tmp_path / "curves.png").read_bytes()[:4] == b"\x89PNG"  # loss and validation curves
    other_variant = train_magicpoint.TrainConfig(variant="L", iterations=4, batch=4, validation_per_category=1)
    with pytest.raises(ValueError, match="another shape.*resume it with its own options"):
        train_magicpoint.run(tmp_path, other_variant)
    shipped = export_weights(tmp_path / "last.pt", tmp_path / "weights.pt")
    assert "optimizer" not in shipped and "rng" not in shipped
    detector = MagicPoint.pretrained("S", path=tmp_path / "weights.pt")  # loads like the shipped weights
    assert detector.heatmap(np.zeros((32, 32), np.uint8)).shape == (32, 32)
    (tmp_path / "junk.pt").write_text("junk")
    with pytest.raises(ValueError, match="not a deepslam weights file or checkpoint"):
        export_weights(tmp_path / "junk.pt", tmp_path / "x.pt")
    size = (tmp_path / "last.pt").stat().st_size
    with pytest.raises(ValueError, match="would overwrite the input"):
        export_weights(tmp_path / "last.pt", tmp_path / "." / "last.pt")
    assert (tmp_path / "last.pt").stat().st_size == size
    (tmp_path / "ck").mkdir()
    os.link(tmp_path / "last.pt", tmp_path / "ck" / "x.pt.tmp")  # a source named like a temporary file
    export_weights(tmp_path / "ck" / "x.pt.tmp", tmp_path / "ck" / "x.pt")
    assert (tmp_path / "ck" / "x.pt.tmp").stat().st_size == size  # not consumed
    os.link(tmp_path / "last.pt", tmp_path / "ck" / "y.pt.partial")
    with pytest.raises(ValueError, match="would overwrite the input"):
        export_weights(tmp_path / "ck" / "y.pt.partial", tmp_path / "ck" / "y.pt")
    assert (tmp_path / "last.pt").stat().st_size == size


class _RunsCode:
    """An object whose unpickling would run a command: what a crafted weights file carries."""

    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return (Path.touch, (self.marker,))


def test_a_crafted_weights_file_is_refused_and_runs_nothing(tmp_path):
    from deepslam.frontend import MagicWarp
    from deepslam.frontend.training.surgery import load_weights

    marker = tmp_path / "ran"
    crafted = tmp_path / "crafted.pt"
    net = MagicPoint.pretrained("S").net
    torch.save({"model": net.state_dict(), "config": {}, "step": 1, "payload": _RunsCode(marker)}, crafted)
    for load in (
        lambda: MagicPoint.pretrained("S", path=crafted),
        lambda: MagicWarp.pretrained(crafted),
        lambda: export_weights(crafted, tmp_path / "out.pt"),
        lambda: load_weights(train_magicpoint.MagicPointNet(), crafted),
    ):
        with pytest.raises(ValueError, match="holds more than tensors and plain data"):
            load()
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "last.pt").write_bytes(crafted.read_bytes())  # the automatic resume reads it too
    with pytest.raises(ValueError, match="holds more than tensors and plain data"):
        train_magicpoint.run(tmp_path / "run", train_magicpoint.TrainConfig(iterations=1, batch=2))
    assert not marker.exists()


def test_weights_of_another_network_are_refused_in_one_line(tmp_path):
    from deepslam.frontend import MagicWarp
    from deepslam.frontend.magicpoint import WEIGHTS

    with pytest.raises(ValueError, match="holds no MagicPoint this version can run"):
        MagicPoint.pretrained("S-HA", path=WEIGHTS / "magicwarp.pt")  # MagicWarp's config and layers
    with pytest.raises(ValueError, match="holds no MagicWarp this version can run"):
        MagicWarp.pretrained(WEIGHTS / "magicpoint_S.pt")
    state = torch.load(WEIGHTS / "magicpoint_S.pt", weights_only=True)
    torch.save({**state, "config": {**state["config"], "head": 16}}, tmp_path / "narrow.pt")
    with pytest.raises(ValueError, match="holds no MagicPoint this version can run"):
        MagicPoint.pretrained("S", path=tmp_path / "narrow.pt")  # a config its tensors do not fit


def test_a_diverging_run_stops_with_its_last_good_checkpoint(tmp_path):
    config = train_magicpoint.TrainConfig(iterations=4, batch=2, validate_every=2, validation_per_category=1)
    train_magicpoint.run(tmp_path, replace(config, iterations=2))
    good = torch.load(tmp_path / "last.pt", weights_only=True)["model"]
    with pytest.raises(RuntimeError, match="diverged"):
        train_magicpoint.run(tmp_path, replace(config, lr=1e30))
    kept = torch.load(tmp_path / "last.pt", weights_only=True)["model"]
    assert all(torch.equal(good[k], kept[k]) for k in good)


@pytest.mark.slow
def test_magicwarp_training_runs_and_resumes(tmp_path):
    config = train_magicwarp.TrainConfig(iterations=2, batch=4, validate_every=2)
    figures = train_magicwarp.run(tmp_path, config)
    assert 0 <= figures["score"] <= 100
    state = torch.load(tmp_path / "last.pt", weights_only=False)
    assert state["step"] == 2 and "rng" in state


@pytest.mark.parametrize(
    "trainer, options, message",
    [
        (train_magicwarp, {"loss_weighting": "points"}, "--loss-weighting"),
        (train_magicwarp, {"geometry_weights": (0, 0, 0, 0, 0)}, "geometry_weights"),
        (train_magicwarp, {"max_extra": -0.1}, "max_extra"),
        (train_magicwarp, {"clean_a_share": 1.5}, "clean_a_share"),
        (train_magicwarp, {"cauchy": -0.05}, "--cauchy"),
        (train_magicwarp, {"lr": 0}, "--lr"),
        (train_magicpoint, {"clean_share": 1.5}, "--clean-share"),
        (train_magicpoint, {"variant": "M"}, "--variant"),
    ],
)
def test_training_options_fail_before_any_work(trainer, options, message):
    with pytest.raises(ValueError, match=message):
        trainer.TrainConfig(**options)


def test_an_interrupted_run_keeps_its_validation_history(tmp_path):
    model = MagicWarpNet(MagicWarpConfig(widths=(4, 4), hidden=8))

    def step_fn(step, rng, batch):
        if step == 2:
            raise KeyboardInterrupt  # killed during the third step, after two validations
        return {"loss": sum(p.sum() for p in model.parameters()) * 0.0}

    with pytest.raises(KeyboardInterrupt):
        train(model, LoopConfig(iterations=5, validate_every=1), tmp_path, step_fn, lambda m: {"score": 1.0}, "score")
    assert [row["step"] for row in json.loads((tmp_path / "history.json").read_text())] == [1, 2]
    assert torch.load(tmp_path / "last.pt", weights_only=False)["step"] == 2


def test_a_resumed_run_whose_validation_changed_restarts_its_best_checkpoint(tmp_path):
    model = MagicWarpNet(MagicWarpConfig(widths=(4, 4), hidden=8))

    def step_fn(step, rng, batch):
        return {"loss": sum(p.sum() for p in model.parameters()) * 0.0}

    train(model, LoopConfig(iterations=2, validate_every=1), tmp_path, step_fn, lambda m: {"score": 90.0}, "score")

    def new_validation(m):  # other figures, with scores on another scale: lower than the old best
        return {"rep@paper:rotation": 60.0, "score": 50.0}

    train(model, LoopConfig(iterations=3, validate_every=1), tmp_path, step_fn, new_validation, "score")
    assert torch.load(tmp_path / "best.pt", weights_only=False)["step"] == 3


@pytest.mark.slow
def test_fine_tuning_starts_from_weights_and_ships_the_moving_average(tmp_path):
    base = train_magicpoint.TrainConfig(iterations=1, batch=4, validate_every=1, validation_per_category=1)
    train_magicpoint.run(tmp_path / "base", base)
    start = torch.load(tmp_path / "base" / "last.pt", weights_only=False)["model"]
    name = "encoder.0.0.weight"

    def tuned(iterations):
        config = train_magicpoint.TrainConfig(
            iterations=iterations,
            batch=4,
            validate_every=1,
            validation_per_category=1,
            ema=0.25,
            init=str(tmp_path / "base" / "last.pt"),
            seed=1,
        )
        train_magicpoint.run(tmp_path / "tuned", config)
        return torch.load(tmp_path / "tuned" / "last.pt", weights_only=False)

    first = tuned(1)
    assert not torch.equal(first["model"][name], start[name])  # it started from base and moved
    assert torch.equal(first["ema"][name], first["model"][name])  # the average starts at the first step's weights
    second = tuned(2)  # resumes, average included: ema = 0.25 * ema + 0.75 * weights
    expected = 0.25 * first["ema"][name] + 0.75 * second["model"][name]
    assert torch.allclose(second["ema"][name], expected, atol=1e-6)
    assert not torch.allclose(second["ema"][name], second["model"][name])
    shipped = export_weights(tmp_path / "tuned" / "last.pt", tmp_path / "weights.pt")
    assert torch.equal(shipped["model"][name], second["ema"][name])


@pytest.mark.slow
def test_init_widens_a_narrower_network_without_changing_what_it_computes(tmp_path):
    narrow, wide = MagicWarpConfig(widths=(8, 8, 16, 16), hidden=16), MagicWarpConfig(widths=(8, 16, 16, 32), hidden=32)
    train_magicwarp.run(
        tmp_path / "narrow", train_magicwarp.TrainConfig(iterations=1, batch=4, validate_every=1), narrow
    )
    weights = tmp_path / "narrow" / "last.pt"
    cells = (torch.rand(3, 130, 15, 20) < 0.1).float()
    start, widened = MagicWarpNet(narrow).eval(), MagicWarpNet(wide).eval()
    load_weights(start, weights)
    load_weights(widened, weights)
    assert torch.allclose(widened(cells), start(cells), atol=1e-5)
    assert sum(p.numel() for p in widened.parameters()) > sum(p.numel() for p in start.parameters())
    with pytest.raises(ValueError, match="another shape"):  # narrowing cannot keep the function
        load_weights(MagicWarpNet(MagicWarpConfig(widths=(8, 8, 8, 16), hidden=16)), weights)
    with pytest.raises(ValueError, match="positive widths"):
        MagicWarpConfig(widths=(8, 0))
    with pytest.raises(ValueError, match="another shape"):  # nor can another layout
        load_weights(MagicWarpNet(MagicWarpConfig(widths=(8, 8, 16, 16), pooled=(2, 2), hidden=16)), weights)


@pytest.mark.slow
def test_init_deepens_a_network_with_identity_blocks(tmp_path):
    shallow = MagicWarpConfig(widths=(8, 8, 16, 16), hidden=16)
    train_magicwarp.run(
        tmp_path / "shallow", train_magicwarp.TrainConfig(iterations=3, batch=4, validate_every=3), shallow
    )
    state = torch.load(tmp_path / "shallow" / "last.pt", weights_only=False)
    del state["config"]["blocks"]  # as saved before the field existed: it takes its default
    torch.save(state, tmp_path / "older.pt")
    (tmp_path / "older").mkdir()
    torch.save(state, tmp_path / "older" / "last.pt")
    train_magicwarp.run(tmp_path / "older", train_magicwarp.TrainConfig(iterations=4, batch=4, validate_every=4))
    assert torch.load(tmp_path / "older" / "last.pt", weights_only=False)["step"] == 4  # resumed
    cells = (torch.rand(3, 130, 15, 20) < 0.1).float()
    start = MagicWarpNet(shallow).eval()
    load_weights(start, tmp_path / "older.pt")
    for deeper in (
        MagicWarpConfig(widths=(8, 8, 8, 16, 16, 16), hidden=16, blocks=3),
        MagicWarpConfig(widths=(8, 8, 8, 8, 16, 16, 24, 24), hidden=32, blocks=4),
    ):  # deeper and wider
        grown = MagicWarpNet(deeper).eval()
        load_weights(grown, tmp_path / "older.pt")
        assert torch.allclose(grown(cells), start(cells), atol=1e-5)
    grown.train()  # with batch statistics the identity blocks are close to, not exactly, identities
    assert (grown(cells) - start.train()(cells)).abs().max() < 0.1
    with pytest.raises(ValueError, match="cannot remove blocks"):
        load_weights(MagicWarpNet(MagicWarpConfig(widths=(8, 16), hidden=16, blocks=1)), tmp_path / "older.pt")
    with pytest.raises(ValueError, match="whole number of stages"):
        MagicWarpConfig(widths=(8, 8, 16, 16), blocks=3)


def _photo_folder(folder: Path, count: int = 3) -> Path:
    """A folder of small synthetic 'photographs' (random rectangles), one sub-folder each."""
    import cv2

    rng = np.random.default_rng(5)
    for index in range(count):
        image = np.full((180, 240), 90, np.uint8)
        for _ in range(12):
            x, y = rng.integers(0, 200), rng.integers(0, 150)
            cv2.rectangle(image, (int(x), int(y)), (int(x + rng.integers(10, 60)), int(y + rng.integers(10, 40))),
                          int(rng.integers(0, 256)), -1)  # fmt: skip
        (folder / f"scene{index}").mkdir(parents=True)
        cv2.imwrite(str(folder / f"scene{index}" / "photo.png"), image)
    return folder


def test_photo_split_keeps_benchmark_photos_out_and_is_stable(tmp_path):
    from deepslam.frontend.evaluation.detector import PHOTOS
    from deepslam.sim import photos, world

    folder = _photo_folder(tmp_path / "photos", 6)
    parts = photos.split((folder,))
    names = [p.name for part in parts.values() for p in part]
    assert set(world._PHOTOS) | set(PHOTOS) <= set(photos.BENCHMARK)
    assert not {n.split(":")[-1] for n in names} & set(photos.BENCHMARK)  # never trained or validated on
    assert parts["validation"] and parts["training"]
    assert photos.split((folder,)) == parts  # the same split every time
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="no photographs"):
        photos.folder_photos(tmp_path / "empty")
    view = photos.random_view(np.zeros((400, 600), np.uint8), np.random.default_rng(0))
    assert view.shape == (120, 160) and view.dtype == np.uint8


def test_soft_targets_spread_a_subpixel_point_within_its_cell():
    from deepslam.frontend.training.adaptation import soft_targets

    targets = soft_targets([np.array([[10.25, 20.5, 0.9], [10.5, 20.5, 0.1]])], (120, 160))
    cell = targets[0, :, 20 // 8, 10 // 8]
    assert cell.sum() == pytest.approx(1.0) and cell[64] == 0  # one point per cell: the best-scoring
    # (10.25, 20.5) -> pixels x 10/11, y 20/21 with weights 0.75/0.25 and 0.5/0.5
    assert cell[(20 % 8) * 8 + 10 % 8] == pytest.approx(0.375)  # channel of pixel (10, 20) in its cell
    assert cell[(21 % 8) * 8 + 11 % 8] == pytest.approx(0.125)
    assert targets[0, 64].sum() == targets.shape[2] * targets.shape[3] - 1  # every other cell is dustbin


def test_an_enlarged_teacher_labels_corners_in_the_views_pixels():
    from deepslam.frontend.magicpoint import VARIANTS, WEIGHTS, MagicPointNet
    from deepslam.frontend.nets import fold_batchnorm, read_weights
    from deepslam.frontend.training.adaptation import AdaptConfig, label_views
    from deepslam.sim.shapes import evaluation_set

    net = MagicPointNet(VARIANTS["S"])
    net.load_state_dict(read_weights(WEIGHTS / "magicpoint_S.pt")[1])
    net = fold_batchnorm(net)
    items = [(image, corners) for _, image, corners in evaluation_set(2, seed=3) if len(corners) >= 4][:4]
    for scale in (1, 2):
        config = AdaptConfig(warps=4, teacher_scale=scale)
        labels = label_views(net, np.stack([image for image, _ in items]), np.random.default_rng(0), config)
        near = []
        for found, (_, corners) in zip(labels, items, strict=True):
            found = found[np.isfinite(found[:, 0]), :2]
            near.append(np.linalg.norm(found[:, None] - np.asarray(corners)[None, :, :2], axis=2).min(axis=1) < 2.0)
        assert np.mean(np.concatenate(near)) > 0.6, scale  # labels sit on true corners, in the view's pixels
    with pytest.raises(ValueError, match="teacher-scale"):
        AdaptConfig(teacher_scale=0)


def test_labels_are_refined_as_configured_and_their_cache_knows_how():
    from deepslam.frontend.magicpoint import WEIGHTS, MagicPoint
    from deepslam.frontend.training.adaptation import AdaptConfig, label_views, labelling_key
    from deepslam.sim.shapes import evaluation_set

    net = MagicPoint.pretrained("S").net
    images = np.stack([image for _, image, _ in evaluation_set(1, seed=5)][:3])
    labels = {
        refine: label_views(net, images, np.random.default_rng(0), AdaptConfig(warps=4, label_refine=refine))
        for refine in ("none", "centroid", "parabola")
    }
    at_pixels = labels["none"]
    assert np.isfinite(at_pixels[:, :, 0]).sum() > 10 and np.array_equal(
        at_pixels[..., :2], np.round(at_pixels[..., :2]), equal_nan=True
    )
    for refine, most in (("centroid", 1.0), ("parabola", 0.5)):  # the same peaks, moved within their pixel's reach
        moved = np.abs(labels[refine][..., :2] - at_pixels[..., :2])
        assert np.array_equal(np.isnan(moved), np.isnan(at_pixels[..., :2])), refine
        assert 0 < np.nanmax(moved) <= most, refine
    detector = WEIGHTS / "magicpoint_S.pt"
    assert "label_refine" not in labelling_key(AdaptConfig(), detector, [], 1)  # centroid labels keep their key
    assert labelling_key(AdaptConfig(label_refine="parabola"), detector, [], 1)["label_refine"] == "parabola"


@pytest.mark.slow
def test_homographic_adaptation_labels_trains_resumes_and_guards_its_cache(tmp_path):
    from deepslam.frontend.training import adaptation

    folder = _photo_folder(tmp_path / "photos")
    config = adaptation.AdaptConfig(
        photos=(str(folder),), views=4, warps=3, iterations=2, batch=4, validate_every=2, rounds=2, validation_views=1
    )
    figures = adaptation.run(tmp_path / "ha", config)
    assert {"rep_clean", "rep_noisy", "loc_clean", "map_clean", "map_noisy", "score"} <= set(figures)
    shard = tmp_path / "ha" / "round2" / "labels" / "shard_000.npz"
    assert shard.exists() and (tmp_path / "ha" / "round2" / "best.pt").exists()
    labelled = shard.stat().st_mtime_ns
    adaptation.run(tmp_path / "ha", config)  # everything done: labels reused, rounds resumed at their end
    assert shard.stat().st_mtime_ns == labelled
    with pytest.raises(ValueError, match="trained on labels of another"):
        adaptation.run(tmp_path / "ha", replace(config, warps=4))
    detector = MagicPoint.pretrained("S-HA", path=tmp_path / "ha" / "round2" / "best.pt")
    assert detector.extraction == EXTRACTION_PRESETS["S-HA"]  # the variant's own extraction
    with pytest.raises(ValueError, match="no folder of photographs"):
        adaptation.run(tmp_path / "other", replace(config, photos=(str(tmp_path / "missing"),)))


@pytest.mark.slow
def test_homographic_adaptation_trains_a_wider_anti_aliased_detector_from_its_teacher(tmp_path):
    from deepslam.frontend.training import adaptation

    config = adaptation.AdaptConfig(
        photos=(str(_photo_folder(tmp_path / "photos")),), views=4, warps=3, iterations=2, batch=4, validate_every=2,
        rounds=1, validation_views=1, widths=(8, 8, 16, 24), head=40, pool="blur",
    )  # fmt: skip
    adaptation.run(tmp_path / "wide", config)  # labelled by S, which max-pools
    detector = MagicPoint.pretrained("S-HA", path=tmp_path / "wide" / "round1" / "best.pt")
    assert detector.net.config == MagicPointConfig((8, 8, 16, 24), 40, "blur")
    with pytest.raises(ValueError, match="--widths"):
        replace(config, widths=(8, 0, 16, 16))
    adaptation.run(tmp_path / "wide_again", config)  # the same training again: the new units follow the seed
    again = MagicPoint.pretrained("S-HA", path=tmp_path / "wide_again" / "round1" / "best.pt").net.state_dict()
    assert all(torch.equal(value, again[name]) for name, value in detector.net.state_dict().items())
    with pytest.raises(ValueError, match="another shape"):  # narrower than its teacher, S: before any labelling
        adaptation.run(tmp_path / "narrow", replace(config, widths=(8, 8, 8, 8)))
    assert not (tmp_path / "narrow" / "round1" / "labels").exists()


def test_shift_consistency_is_zero_for_a_heatmap_that_moves_with_its_view():
    from deepslam.frontend.training.adaptation import shift_disagreement, shifted_views

    rng = np.random.default_rng(4)
    views = rng.integers(0, 256, (6, 120, 160), dtype=np.uint8)
    moved, shifts = shifted_views(views, rng)
    assert np.all((shifts >= 0) & (shifts < 8)) and np.all(shifts.any(axis=1))  # within a cell, never none
    for view, image, (dx, dy) in zip(views, moved, shifts, strict=True):
        assert np.array_equal(image[dy:, dx:], view[: 120 - dy, : 160 - dx])
    heat = torch.from_numpy(rng.random((6, 120, 160), dtype=np.float32))
    follows = torch.stack([torch.roll(h, (int(dy), int(dx)), (0, 1)) for h, (dx, dy) in zip(heat, shifts, strict=True)])
    assert float(shift_disagreement(heat, follows, shifts)) == 0.0
    assert float(shift_disagreement(heat, heat.flip(1), shifts)) > 0.1


@pytest.mark.slow
def test_homographic_adaptation_trains_with_shift_consistency(tmp_path):
    from deepslam.frontend.training import adaptation

    config = adaptation.AdaptConfig(
        photos=(str(_photo_folder(tmp_path / "photos")),), views=4, warps=3, iterations=2, batch=4, validate_every=2,
        rounds=1, validation_views=1, shift_consistency=1.0,
    )  # fmt: skip
    adaptation.run(tmp_path / "shift", config)
    plain = tmp_path / "plain"
    adaptation.run(plain, replace(config, shift_consistency=0.0))
    trained = MagicPoint.pretrained("S-HA", path=tmp_path / "shift" / "round1" / "best.pt").net.state_dict()
    without = MagicPoint.pretrained("S-HA", path=plain / "round1" / "best.pt").net.state_dict()
    assert not all(torch.equal(value, without[name]) for name, value in trained.items())  # the term moved the weights
    with pytest.raises(ValueError, match="--shift-consistency"):
        replace(config, shift_consistency=-1.0)


def _torchrun(out: Path, iterations: int, batch: int = 4):
    import subprocess
    import sys

    command = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2", "-m",
               "deepslam", "train", "magicpoint", "--iterations", str(iterations), "--batch", str(batch),
               "--validate-every", "2", "--validation-per-category", "1", "--out", str(out), "-q"]  # fmt: skip
    return subprocess.run(command, capture_output=True, text=True, timeout=600)


@pytest.mark.slow
def test_two_ranks_train_in_step_and_resume_their_streams(tmp_path):
    straight = _torchrun(tmp_path / "straight", 6)
    assert straight.returncode == 0, straight.stderr[-2000:]
    stopped = _torchrun(tmp_path / "resumed", 4)  # stopped at step 4 ...
    assert stopped.returncode == 0, stopped.stderr[-2000:]
    resumed = _torchrun(tmp_path / "resumed", 6)  # ... and resumed: every rank continues its own stream
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    a, b = (torch.load(tmp_path / run / "last.pt", weights_only=True) for run in ("straight", "resumed"))
    assert a["step"] == b["step"] == 6 and len(a["rngs"]) == 2 and a["rngs"][0] != a["rngs"][1]
    assert all(torch.equal(a["model"][k], b["model"][k]) for k in a["model"])  # the same run, interrupted or not
    # (the ranks' parameters are compared after every step inside the loop; a mismatch stops the run)
    odd = _torchrun(tmp_path / "odd", 2, batch=3)
    assert odd.returncode != 0 and "--batch 3 does not divide among 2 ranks" in odd.stderr


@pytest.mark.slow
def test_the_same_seed_trains_the_same_bytes_interrupted_or_not(tmp_path):
    config = train_magicpoint.TrainConfig(iterations=4, batch=2, validate_every=2, validation_per_category=1)
    train_magicpoint.run(tmp_path / "a", config)
    train_magicpoint.run(tmp_path / "b", replace(config, iterations=2))  # interrupted at step 2 ...
    train_magicpoint.run(tmp_path / "b", config)  # ... and resumed
    a, b = (torch.load(tmp_path / run / "last.pt", weights_only=True)["model"] for run in ("a", "b"))
    assert all(torch.equal(a[k], b[k]) for k in a)
