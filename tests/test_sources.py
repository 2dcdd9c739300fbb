"""Running on recorded data: ROS 2 bags, TUM RGB-D and EuRoC/ASL folders made from a simulated run give the
drift that replaying the run's own log gives; bad inputs get one-line errors before any work."""

import cv2
import numpy as np
import pytest

from deepslam.backend.config import OdometryConfig
from deepslam.backend.evaluation.runs import replay, simulate
from deepslam.cli import main
from deepslam.frontend.config import TrackerConfig
from deepslam.geometry import quaternion_from_matrix
from deepslam.inputs import Calibration, Rectifier, SourceError, SourceOptions, associate, open_source
from deepslam.logs.reader import read_frames, read_metadata
from deepslam.sim.scenario import ScenarioConfig

CLASSICAL = TrackerConfig("classical")


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """A simulated run's log, its frames, and the drift of replaying that log with the classical front-end."""
    folder = tmp_path_factory.mktemp("recorded")
    log = folder / "run.mcap"
    simulate(ScenarioConfig(frames=20, seed=2), CLASSICAL, OdometryConfig(), log, {}, progress=False)
    frames = list(read_frames(log))
    reference = replay(log, CLASSICAL, OdometryConfig(), folder / "reference.mcap", progress=False)
    return folder, frames, reference["summary"]


def _write_bag(path, frames, encoding: str, distortion=(0.0, 0.0, 0.0, 0.0, 0.0), tamper=None):
    """A rosbag2 folder of the frames: images, CameraInfo and Odometry ground truth; ``tamper(topic kind,
    message, types)``, if given, may return another message for each one written."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    types = store.types
    Time, Header = types["builtin_interfaces/msg/Time"], types["std_msgs/msg/Header"]
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        image = writer.add_connection("/robot/front/image_raw", "sensor_msgs/msg/Image", typestore=store)
        info = writer.add_connection("/robot/front/info", "sensor_msgs/msg/CameraInfo", typestore=store)
        truth = writer.add_connection("/mocap/odom", "nav_msgs/msg/Odometry", typestore=store)
        for f in frames:
            header = Header(stamp=Time(sec=f.stamp_ns // 10**9, nanosec=f.stamp_ns % 10**9), frame_id="camera")
            h, w = f.image.shape
            pixels = f.image if encoding == "mono8" else np.repeat(f.image[..., None], 3, axis=2)
            step = w * (1 if encoding == "mono8" else 3)
            message = types["sensor_msgs/msg/Image"](header=header, height=h, width=w, encoding=encoding,
                                                     is_bigendian=0, step=step, data=pixels.reshape(-1))  # fmt: skip
            message = tamper("image", message, types) if tamper else message
            writer.write(image, f.stamp_ns, store.serialize_cdr(message, image.msgtype))
            roi = types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
            camera = types["sensor_msgs/msg/CameraInfo"](
                header=header, height=h, width=w, distortion_model="plumb_bob", d=np.array(distortion),
                k=f.K.ravel(), r=np.eye(3).ravel(), p=np.hstack([f.K, np.zeros((3, 1))]).ravel(),
                binning_x=0, binning_y=0, roi=roi,
            )  # fmt: skip
            camera = tamper("info", camera, types) if tamper else camera
            writer.write(info, f.stamp_ns, store.serialize_cdr(camera, info.msgtype))
            x, y, z = f.T_groundtruth[:3, 3]
            q = quaternion_from_matrix(f.T_groundtruth[:3, :3])
            Pose, Point, Quaternion = (types[f"geometry_msgs/msg/{n}"] for n in ("Pose", "Point", "Quaternion"))
            pose = Pose(position=Point(x=x, y=y, z=z), orientation=Quaternion(x=q[0], y=q[1], z=q[2], w=q[3]))
            covariance = np.zeros(36)
            odometry = types["nav_msgs/msg/Odometry"](
                header=header, child_frame_id="camera",
                pose=types["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=covariance),
                twist=types["geometry_msgs/msg/TwistWithCovariance"](
                    twist=types["geometry_msgs/msg/Twist"](
                        linear=types["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                        angular=types["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                    ),
                    covariance=covariance,
                ),
            )  # fmt: skip
            odometry = tamper("truth", odometry, types) if tamper else odometry
            writer.write(truth, f.stamp_ns, store.serialize_cdr(odometry, truth.msgtype))


def _tum_line(stamp_ns: int, T) -> str:
    q = quaternion_from_matrix(T[:3, :3])
    return f"{stamp_ns // 10**9}.{stamp_ns % 10**9:09d} " + " ".join(repr(float(v)) for v in (*T[:3, 3], *q))


def _write_tum(folder, frames) -> None:
    (folder / "rgb").mkdir(parents=True)
    lines = []
    for f in frames:
        name = f"rgb/{f.stamp_ns}.png"
        cv2.imwrite(str(folder / name), f.image)
        lines.append(f"{f.stamp_ns // 10**9}.{f.stamp_ns % 10**9:09d} {name}")
    (folder / "rgb.txt").write_text("# timestamp filename\n" + "\n".join(lines) + "\n")
    (folder / "groundtruth.txt").write_text("\n".join(_tum_line(f.stamp_ns, f.T_groundtruth) for f in frames) + "\n")


def _write_calibration(path, K, size) -> None:
    fx, fy, cx, cy = (repr(float(v)) for v in (K[0, 0], K[1, 1], K[0, 2], K[1, 2]))
    path.write_text(f"fx: {fx}\nfy: {fy}\ncx: {cx}\ncy: {cy}\nwidth: {size[1]}\nheight: {size[0]}\n"
                    "distortion: [0, 0, 0, 0, 0]\n")  # fmt: skip


def _write_euroc(folder, frames) -> None:
    camera = folder / "mav0" / "cam0"
    (camera / "data").mkdir(parents=True)
    for f in frames:
        cv2.imwrite(str(camera / "data" / f"{f.stamp_ns}.png"), f.image)
    (camera / "data.csv").write_text(
        "#timestamp [ns],filename\n" + "".join(f"{f.stamp_ns},{f.stamp_ns}.png\n" for f in frames)
    )
    K, (h, w) = frames[0].K, frames[0].image.shape
    intrinsics = ", ".join(repr(float(v)) for v in (K[0, 0], K[1, 1], K[0, 2], K[1, 2]))
    identity = ", ".join(str(v) for v in np.eye(4, dtype=int).ravel())
    (camera / "sensor.yaml").write_text(
        f"%YAML:1.0\nsensor_type: camera\nT_BS:\n  cols: 4\n  rows: 4\n  data: [{identity}]\n"
        f"resolution: [{w}, {h}]\ncamera_model: pinhole\nintrinsics: [{intrinsics}]\n"
        "distortion_model: radial-tangential\ndistortion_coefficients: [0.0, 0.0, 0.0, 0.0]\n"
    )
    truth = folder / "mav0" / "state_groundtruth_estimate0"
    truth.mkdir()
    rows = []
    for f in frames:
        q = quaternion_from_matrix(f.T_groundtruth[:3, :3])
        values = [*f.T_groundtruth[:3, 3], q[3], q[0], q[1], q[2]]
        rows.append(f"{f.stamp_ns}," + ",".join(repr(float(v)) for v in values) + ",0,0,0")
    (truth / "data.csv").write_text("#timestamp,p_x,p_y,p_z,q_w,q_x,q_y,q_z,v_x,v_y,v_z\n" + "\n".join(rows) + "\n")


@pytest.mark.parametrize("kind", ["bag mono8", "bag rgb8", "tum", "euroc"])
def test_recorded_data_replays_to_the_drift_of_the_simulated_log(recorded, kind, tmp_path):
    folder, frames, reference = recorded
    options = SourceOptions()
    if kind.startswith("bag"):
        source = tmp_path / "bag"
        _write_bag(source, frames, kind.split()[1])
        options = SourceOptions(groundtruth_topic="/mocap/odom")
    elif kind == "tum":
        source = tmp_path / "tum"
        _write_tum(source, frames)
        _write_calibration(tmp_path / "camera.yaml", frames[0].K, frames[0].image.shape)
        options = SourceOptions(calibration=str(tmp_path / "camera.yaml"))
    else:
        source = tmp_path / "euroc"
        _write_euroc(source, frames)
    result = replay(source, CLASSICAL, OdometryConfig(), tmp_path / "out.mcap", progress=False, source_options=options)
    for key in ("ate_se3", "ate_sim3", "rpe_trans", "final_drift_pct"):
        assert result["summary"][key] == pytest.approx(reference[key], rel=1e-6, abs=1e-9), key
    meta = read_metadata(tmp_path / "out.mcap")
    assert meta["source"] in ("ROS 2 bag", "TUM RGB-D folder", "EuRoC/ASL folder") and meta["source_calibration"]


def test_scale_none_reports_only_what_survives_a_sim3_alignment(recorded, tmp_path, capsys):
    folder, frames, _ = recorded
    _write_tum(tmp_path / "tum", frames[:12])
    truth = (tmp_path / "tum" / "groundtruth.txt").read_text().splitlines()
    (tmp_path / "tum" / "groundtruth.txt").write_text("\n".join(truth[::2]) + "\n")  # the motion capture missed half
    _write_calibration(tmp_path / "camera.yaml", frames[0].K, frames[0].image.shape)
    argv = ["replay", str(tmp_path / "tum"), "--frontend", "classical", "--calibration", str(tmp_path / "camera.yaml"),
            "--out", str(tmp_path / "o.mcap"), "-q"]  # fmt: skip
    gt = main([*argv, "--scale", "gt"])
    assert gt == 1 and "--scale gt needs ground truth in every frame, 6 of 12" in capsys.readouterr().err
    assert main([*argv, "--scale", "none"]) == 0
    out = capsys.readouterr().out
    figures = dict(line.split()[:2] for line in out.splitlines() if line.startswith("  ") and len(line.split()) == 2)
    assert "up to scale" in out and "ate_sim3" in figures and "ate_se3" not in figures
    assert figures["frames_with_truth"] == "6" and figures["frames"] == "12"  # the run's own figures need no truth


def test_undistortion_and_resizing_keep_the_pinhole_geometry():
    K = np.array([[120.0, 0, 79.5], [0, 120.0, 59.5], [0, 0, 1]])
    distortion = (-0.3, 0.1, 0.001, -0.002, 0.0)
    calibration = Calibration.checked(K, distortion, "plumb_bob", (120, 160), "test")
    rectify = Rectifier(calibration, (240, 320))
    # a bright dot where the distorted camera sees a point; after rectification it is where a pinhole sees it
    point = np.array([[0.25, -0.15, 1.0]])
    seen, _ = cv2.projectPoints(point, np.zeros(3), np.zeros(3), K, np.array(distortion))
    image = np.zeros((120, 160), np.uint8)
    cv2.circle(image, tuple(int(round(v)) for v in seen.ravel()), 2, 255, -1)
    rectified = rectify(image).astype(float)
    ys, xs = np.mgrid[0:240, 0:320]
    found = np.array([(xs * rectified).sum(), (ys * rectified).sum()]) / rectified.sum()
    expected = (rectify.K @ point.ravel())[:2]
    assert np.linalg.norm(found - expected) < 1.0  # pixels of the 320x240 result


def test_association_follows_tums_rule():
    ms = 1_000_000
    assert associate([0, 100 * ms, 200 * ms], [5 * ms, 95 * ms, 500 * ms]) == {0: 0, 1: 1}  # none within 20 ms of 200
    assert associate([0, 30 * ms], [25 * ms]) == {1: 0}  # the closer pair wins, each truth used once


def test_bad_recorded_inputs_get_one_line_errors_before_any_work(recorded, tmp_path):
    folder, frames, _ = recorded
    bag = tmp_path / "bag"
    _write_bag(bag, frames[:3], "mono8")
    (tmp_path / "clip.mp4").write_bytes(b"not read: the option is refused first")
    for source, options, message in [
        (bag, SourceOptions(image_topic="/nope"), "no topic /nope; the bag has /mocap/odom"),
        (bag, SourceOptions(groundtruth_topic="/robot/front/info"), "is a sensor_msgs/msg/CameraInfo, not one of"),
        (tmp_path, SourceOptions(), "neither a TUM RGB-D"),
        (tmp_path / "missing", SourceOptions(), "no such file or folder"),
        (bag, SourceOptions(fps=5.0), "--fps applies to video files only .this ROS 2 bag has its own stamps."),
        (tmp_path / "clip.mp4", SourceOptions(image_topic="/cam"), "--image-topic applies to ROS 2 bags only, not to"),
    ]:
        with pytest.raises(SourceError, match=message):
            open_source(source, options)
    tum = tmp_path / "tum"
    _write_tum(tum, frames[:3])
    with pytest.raises(SourceError, match="--groundtruth-topic applies to ROS 2 bags only, not to a TUM RGB-D folder"):
        open_source(tum, SourceOptions(groundtruth_topic="/mocap"))
    with pytest.raises(SourceError, match="carries no calibration"):
        open_source(tum)
    (tum / "rgb.txt").write_text((tum / "rgb.txt").read_text().replace(".", ".9", 1))  # the first frame comes last
    _write_calibration(tmp_path / "c.yaml", frames[0].K, frames[0].image.shape)
    with pytest.raises(SourceError, match="timestamps out of order"):
        open_source(tum, SourceOptions(calibration=str(tmp_path / "c.yaml")))
    euroc = tmp_path / "euroc"
    _write_euroc(euroc, frames[:3])
    cv2.imwrite(str(next((euroc / "mav0" / "cam0" / "data").iterdir())), np.zeros((64, 64), np.uint8))
    with pytest.raises(SourceError, match="images change size"):
        open_source(euroc)
    assert main(["replay", str(euroc), "--out", str(tmp_path / "x.mcap")]) == 1
    assert not (tmp_path / "x.mcap").exists() and not (tmp_path / "x.mcap.partial").exists()


def test_a_bag_is_closed_once_checked_refused_or_read(recorded, tmp_path):
    import gc
    import warnings

    folder, frames, _ = recorded
    bag = tmp_path / "bag"
    _write_bag(bag, frames[:3], "mono8")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ResourceWarning)
        with pytest.raises(SourceError, match="no topic /nope"):
            open_source(bag, SourceOptions(image_topic="/nope"))
        source = open_source(bag)
        assert [len(list(source.frames())) for _ in range(2)] == [3, 3]  # read twice, in full
        assert len(list(zip(source.frames(), source.frames(), strict=True))) == 3  # and twice at once
        first = next(source.frames())  # a reading left halfway
        del first
        gc.collect()
    assert not [warning for warning in caught if issubclass(warning.category, ResourceWarning)]


def test_an_image_too_large_to_hold_is_refused_from_its_header_before_decoding(recorded, tmp_path):
    import struct
    import time

    folder, frames, _ = recorded
    tum = tmp_path / "tum"
    _write_tum(tum, frames[:3])
    first = next(iter(sorted((tum / "rgb").iterdir())))
    png = bytearray(first.read_bytes())
    png[16:24] = struct.pack(">II", 20000, 20000)  # the header says 20000x20000 (a few KB on disk)
    first.write_bytes(bytes(png))
    _write_calibration(tmp_path / "c.yaml", frames[0].K, frames[0].image.shape)
    started = time.time()
    with pytest.raises(SourceError, match="20000x20000 image is over the"):
        open_source(tum, SourceOptions(calibration=str(tmp_path / "c.yaml")))
    assert time.time() - started < 5


def _mend(path, old: str, new: str) -> None:
    path.write_text(path.read_text().replace(old, new, 1))


def _last_line(path, new: str) -> None:
    lines = path.read_text().splitlines()
    path.write_text("\n".join(lines[:-1] + [new]) + "\n")


GT, CAM, STATE = "groundtruth.txt", "mav0/cam0", "mav0/state_groundtruth_estimate0/data.csv"
ZEROS = "distortion: [0, 0, 0, 0, 0]"


def _field(name: str, value: str):
    """A damage that gives the calibration file's ``name`` field another ``value``."""
    return lambda c: c.write_text(c.read_text().replace(f"{name}: ", f"{name}: {value} #", 1))


@pytest.mark.parametrize(
    "kind, damage, message",
    [
        ("tum", lambda d: _last_line(d / "rgb.txt", "1704067200.5"), r"rgb.txt line 4: no filename"),
        ("tum", lambda d: _last_line(d / GT, "1704067200.5 1 2 3"), r"groundtruth.txt line 3: no qx"),
        ("tum", lambda d: _mend(d / "rgb.txt", "rgb/", "../"), r"rgb.txt line 2, filename: '\.\./.*' lies outside"),
        ("tum", lambda d: _mend(d / "rgb.txt", "rgb/", "/etc/"), r"rgb.txt line 2, filename: '/etc/.*' lies outside"),
        ("tum", lambda d: _mend(d / "rgb.txt", "17040", "-17040"), r"line 2, timestamp: '-17040.*' is not a time"),
        ("tum", lambda d: _last_line(d / GT, "1704067200.5 1 2 3 0 0 0 0"), r"line 3: the quaternion .* is not a unit"),
        ("tum", lambda d: _last_line(d / GT, "1704067200.5 nan 2 3 0 0 0 1"), r"line 3, position: 'nan' is not finite"),
        ("euroc", lambda d: _last_line(d / CAM / "data.csv", "1704067200500000000,"), r"data.csv line 4: no filename"),
        ("euroc", lambda d: _last_line(d / STATE, "1,2,3,4"), r"data.csv line 4: no q_w"),
        ("euroc", lambda d: _mend(d / CAM / "sensor.yaml", "T_BS:\n", "T_BS: 5\nx:\n"), r"T_BS must be a mapping"),
        ("euroc", lambda d: (d / CAM / "sensor.yaml").write_text("- 1\n- 2\n"), r"expected a mapping"),
        ("calibration", lambda c: _mend(c, ZEROS, "distortion: 5"), r"distortion must be a list"),
        ("calibration", lambda c: _mend(c, ZEROS, "distortion: [1e6, 0, 0, 0, 0]"), r"distortion coefficients over"),
        ("calibration", _field("width", "0"), r"width and height must both be positive"),
        ("calibration", lambda c: [_field("width", "-160")(c), _field("height", "-120")(c)], r"must both be positive"),
        ("calibration", _field("width", "320"), r"declares 120x320 images, the input's are 120x160"),
        ("calibration", _field("fx", "true"), r"fx must be a finite number"),
        ("calibration", lambda c: _mend(c, "cy: ", "cyy: "), r"c.yaml, line 4: unknown key 'cyy' \(known: fx, fy"),
        ("calibration", lambda c: c.write_text(c.read_text().replace("fy: ", "# fy: ")), r"c.yaml: fy is missing"),
        ("calibration", _field("fx", "1e300"), r"focal lengths .* are not plausible"),
        ("calibration", _field("fx", "1e-300"), r"focal lengths .* are not plausible"),
    ],
)
def test_every_field_of_a_dataset_is_checked_with_a_line_naming_file_line_and_field(
    recorded, tmp_path, kind, damage, message
):
    _, frames, _ = recorded
    calibration = tmp_path / "c.yaml"
    _write_calibration(calibration, frames[0].K, frames[0].image.shape)
    folder = tmp_path / "data"
    if kind == "euroc":
        _write_euroc(folder, frames[:3])
    else:
        _write_tum(folder, frames[:3])
    damage(calibration if kind == "calibration" else folder)
    options = SourceOptions(calibration=None if kind == "euroc" else str(calibration))
    with pytest.raises(SourceError, match=message) as error:
        open_source(folder, options)
    assert "\n" not in str(error.value) and ("c.yaml" if kind == "calibration" else str(folder)) in str(error.value)


def test_calibration_is_refused_where_it_does_not_apply(recorded, tmp_path):
    folder, frames, _ = recorded
    _write_calibration(tmp_path / "c.yaml", frames[0].K, frames[0].image.shape)
    with pytest.raises(SourceError, match="--calibration does not apply to a deepslam log"):
        open_source(folder / "run.mcap", SourceOptions(calibration=str(tmp_path / "c.yaml")))


def test_a_video_file_replays_with_a_calibration_and_its_frame_rate(recorded, tmp_path):
    _, frames, _ = recorded
    video = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10, frames[0].image.shape[::-1], False)
    for frame in frames:
        writer.write(frame.image)
    writer.release()
    _write_calibration(tmp_path / "c.yaml", frames[0].K, frames[0].image.shape)
    source = open_source(video, SourceOptions(calibration=str(tmp_path / "c.yaml")))
    loaded = list(source.frames())
    assert len(source) == len(loaded) == len(frames) and source.frames_with_truth == 0
    assert [f.stamp_ns for f in loaded[:3]] == [0, 100_000_000, 200_000_000]  # 10 frames a second
    assert np.abs(loaded[5].image.astype(int) - frames[5].image).mean() < 8  # MJPEG keeps the picture
    out = tmp_path / "replayed.mcap"
    argv = ["replay", str(video), "--calibration", str(tmp_path / "c.yaml"), "--fps", "30", "--scale", "none"]
    assert main([*argv, "-q", "--frontend", "classical", "--out", str(out)]) == 0
    assert read_frames(out).__next__().stamp_ns == 0 and len(list(read_frames(out))) == len(frames)
    with pytest.raises(SourceError, match="carries no calibration"):
        open_source(video)
