"""The MCAP export (``scenarios.export.mcap``) read back by readers nobody here wrote: the
``rosbags`` library (its own MCAP reader, CDR deserialiser and ROS 2 Humble type store) and
Rerun's MCAP importer, against what the run held and the simulator's truth."""

from __future__ import annotations

import dataclasses
import io
import math
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
import zstandard
from mcap.reader import make_reader
from mcap.records import Chunk, ChunkIndex, Footer, MetadataIndex, SummaryOffset
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter
from mcap_ros2._dynamic import serialize_dynamic
from rosbags.highlevel import AnyReader
from rosbags.interfaces import QosDurability
from rosbags.typesys import Stores, get_typestore
from scipy.spatial.transform import Rotation

from scenarios.export.mcap import (
    IMU_TOPIC,
    TOPICS,
    ZSTD_LEVEL,
    McapExporter,
    _camera_info,
    _image_cdr,
    _LevelledWriter,
    _restamped,
    estimates_topic,
)
from scenarios.export.ros2_msgs import msgdef
from scenarios.run.runner import run_scenario
from scenarios.scenario import builtin
from vnav.camera import PinholeCamera
from vnav.cone import TRAFFIC_CONE
from vnav.obstacle_map import footprint_radius_m

HUMBLE = get_typestore(Stores.ROS2_HUMBLE)
RERUN = Path(sys.executable).parent / "rerun"
"""The ``rerun`` command line of the installed rerun-sdk."""


class _Keeper:
    """Forwards the run to the exporter and keeps a copy of every record and image (the
    renderer reuses its buffers)."""

    def __init__(self, exporter: McapExporter, fail_at_tick: int | None = None) -> None:
        self.exporter = exporter
        self.fail_at_tick = fail_at_tick
        self.records, self.rgb, self.depth = [], [], []

    def start(self, spec, seed, camera, scenery) -> None:
        self.camera, self.scenery = camera, scenery
        self.exporter.start(spec, seed, camera, scenery)

    def on_tick(self, record, rgb, depth_m) -> None:
        if record.tick == self.fail_at_tick:
            raise RuntimeError("the run fails here")
        self.records.append(record)
        self.rgb.append(np.array(rgb, copy=True))
        self.depth.append(None if depth_m is None else np.array(depth_m, copy=True))
        self.exporter.on_tick(record, rgb, depth_m)

    def abort(self) -> None:
        self.exporter.abort()


def _export(name: str, duration_s: float, out: Path):
    spec = dataclasses.replace(builtin.load(name), duration_s=duration_s)
    keeper = _Keeper(McapExporter(out, name))
    result = run_scenario(spec, seed=1, observer=keeper)
    exported = keeper.exporter.finish(result)
    return spec, keeper, result, exported, out / f"{name}.mcap"


@pytest.fixture(scope="module")
def latency(tmp_path_factory):
    """The ``latency`` built-in for 1 s (a camera clock 20 ms off, so that the stamps start
    at 1 s; images and depth; four methods' estimates), exported."""
    return _export("latency", 1.0, tmp_path_factory.mktemp("mcap"))


def _messages(path: Path) -> dict[str, list]:
    """Every message by topic, in log-time order: ``(log_time_ns, message, connection)``."""
    out: dict[str, list] = {}
    with AnyReader([path], default_typestore=HUMBLE) as reader:
        for conn, log_time, raw in reader.messages():
            out.setdefault(conn.topic, []).append(
                (log_time, reader.deserialize(raw, conn.msgtype), conn)
            )
    return out


def _ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def _pose(translation, rotation) -> np.ndarray:
    """A 4x4 from a ROS translation and quaternion, by SciPy (not vnav)."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat([rotation.x, rotation.y, rotation.z, rotation.w]).as_matrix()
    T[:3, 3] = [translation.x, translation.y, translation.z]
    return T


def test_the_bag_read_by_rosbags_is_the_run(latency):
    """Every message, deserialised by rosbags with the ROS 2 Humble types: /tf is the true body
    pose of each image (1e-9), /tf_static the true mount of every tick, latched; the camera
    info the camera's K (and the MuJoCo camera's, from the field of view), the images byte for
    byte those rendered, the depth the rendered depth to the millimetre (16UC1), the ground
    truth the body pose, the estimates each method's; all stamped at the image's camera-clock
    stamp plus the whole second the 20 ms clock offset needs to keep ROS time positive."""
    spec, keeper, result, exported, path = latency
    assert exported.written == ("latency.mcap",)
    assert exported.note == "no /imu: the scenario has no [imu]"
    records = keeper.records
    assert len(records) == len(result.ticks) > 5
    offset_s = spec.timing.camera_clock_offset_s
    assert offset_s == pytest.approx(0.02)
    origin_ns = 1_000_000_000  # ceil(0.02 s): the documented whole-second origin
    stamps = [round(r.timing.stamp_cam_s * 1e9) + origin_ns for r in records]
    order = np.argsort(stamps, kind="stable")
    by_topic = _messages(path)
    methods = {m for r in records for d in r.detections for m in d.estimates_w}
    assert len(methods) >= 3
    assert set(by_topic) == set(TOPICS) | {estimates_topic(m) for m in methods}

    tf = by_topic["/tf"]
    assert len(tf) == len(records)
    for (log_time, msg, _), i in zip(tf, order, strict=True):
        (t,) = msg.transforms
        assert (t.header.frame_id, t.child_frame_id) == ("map", "base_link")
        assert _ns(t.header.stamp) == log_time == stamps[i]
        np.testing.assert_allclose(
            _pose(t.transform.translation, t.transform.rotation), records[i].T_w_b, atol=1e-9
        )

    ((log_time, static, conn),) = by_topic["/tf_static"]
    (qos,) = conn.ext.offered_qos_profiles
    assert qos.durability == QosDurability.TRANSIENT_LOCAL
    assert by_topic["/tf"][0][2].ext.offered_qos_profiles[0].durability == QosDurability.VOLATILE
    (t,) = static.transforms
    assert (t.header.frame_id, t.child_frame_id) == ("base_link", "camera_optical_frame")
    assert log_time == origin_ns - round(offset_s * 1e9) <= min(stamps)  # the flight's start
    T_b_c = _pose(t.transform.translation, t.transform.rotation)
    for r in records:
        np.testing.assert_allclose(T_b_c, r.T_b_c, atol=1e-9)

    cam = spec.scene.camera
    f_px = (cam.height / 2) / math.tan(math.radians(cam.fovy_deg) / 2)  # MuJoCo's camera
    K = np.array([[f_px, 0, (cam.width - 1) / 2], [0, f_px, (cam.height - 1) / 2], [0, 0, 1]])
    infos = by_topic["/camera/camera_info"]
    assert len(infos) == len(records)
    for (log_time, info, _), i in zip(infos, order, strict=True):
        assert _ns(info.header.stamp) == log_time == stamps[i]
        assert info.header.frame_id == "camera_optical_frame"
        assert (info.width, info.height) == (cam.width, cam.height)
        assert info.distortion_model == "plumb_bob"
        np.testing.assert_array_equal(info.d, np.zeros(5))
        np.testing.assert_allclose(info.k.reshape(3, 3), K, rtol=1e-12)
        np.testing.assert_array_equal(info.k.reshape(3, 3), keeper.camera.K)
        np.testing.assert_array_equal(info.p.reshape(3, 4), np.hstack([keeper.camera.K, [[0]] * 3]))
        np.testing.assert_array_equal(info.r.reshape(3, 3), np.eye(3))

    images = by_topic["/camera/image_raw"]
    assert len(images) == len(records)
    for (_, image, _), i in zip(images, order, strict=True):
        assert _ns(image.header.stamp) == stamps[i]
        assert (image.encoding, image.is_bigendian, image.step) == ("rgb8", 0, 3 * cam.width)
        assert image.data.tobytes() == keeper.rgb[i].tobytes()

    depths = by_topic["/camera/depth/image_raw"]
    assert len(depths) == len(records)
    for (_, depth, _), i in zip(depths, order, strict=True):
        assert (depth.encoding, depth.is_bigendian, depth.step) == ("16UC1", 0, 2 * cam.width)
        mm = np.frombuffer(depth.data.tobytes(), dtype="<u2").reshape(cam.height, cam.width)
        # The rendered depth to the millimetre where there is a return nearer than the far
        # plane and than 65.535 m, the most 16 bits hold; 0 (no measurement) elsewhere.
        depth_m = keeper.depth[i]
        valid = (depth_m > 0) & (depth_m < spec.scene.zfar_m) & (depth_m < 65.5355)
        assert valid.any() and (~valid).any()  # the ground and the sky
        assert np.all(np.abs(mm[valid] / 1000.0 - depth_m[valid]) <= 0.0005 + 1e-6)
        assert not mm[~valid].any()

    poses = by_topic["/ground_truth/pose"]
    for (_, pose, _), i in zip(poses, order, strict=True):
        assert pose.header.frame_id == "map" and _ns(pose.header.stamp) == stamps[i]
        np.testing.assert_allclose(
            _pose(pose.pose.position, pose.pose.orientation), records[i].T_w_b, atol=1e-9
        )

    for method in methods:
        want = sorted(
            (stamps[k], tuple(d.estimates_w[method]))
            for k, r in enumerate(records)
            for d in r.detections
            if method in d.estimates_w
        )
        got = sorted(
            (_ns(p.header.stamp), (p.point.x, p.point.y, p.point.z))
            for _, p, _ in by_topic[estimates_topic(method)]
        )
        assert [s for s, _ in got] == [s for s, _ in want]
        np.testing.assert_array_equal([p for _, p in got], [p for _, p in want])
        assert all(p.header.frame_id == "map" for _, p, _ in by_topic[estimates_topic(method)])


def test_evo_reads_the_ground_truth_as_the_runs_trajectory(latency):
    """evo's ROS 2 bag reader (``file_interface.read_bag_trajectory``, through rosbags'
    rosbag2 reader) takes ``/ground_truth/pose`` as a trajectory: its stamps the images'
    (seconds), its positions and orientations (evo's w x y z) the true body poses."""
    from evo.tools import file_interface
    from rosbags.rosbag2 import Reader

    _, keeper, _, _, path = latency
    with Reader(path) as reader:
        traj = file_interface.read_bag_trajectory(reader, "/ground_truth/pose")
    records = sorted(keeper.records, key=lambda r: r.timing.stamp_cam_s)
    assert traj.num_poses == len(records)
    np.testing.assert_allclose(
        traj.timestamps, [r.timing.stamp_cam_s + 1.0 for r in records], rtol=0, atol=1e-9
    )
    np.testing.assert_allclose(traj.positions_xyz, [r.T_w_b[:3, 3] for r in records], atol=1e-12)
    R_w_b = Rotation.from_quat(traj.orientations_quat_wxyz, scalar_first=True).as_matrix()
    np.testing.assert_allclose(R_w_b, [r.T_w_b[:3, :3] for r in records], atol=1e-12)


def test_the_cones_are_latched_markers_at_the_true_cones(latency):
    """One TRIANGLE_LIST marker per true cone, posed at its base centre in ``map``, its
    triangles within the standard cone's footprint and height; together every triangle of the
    simulator's cone meshes; transient local."""
    spec, keeper, _, _, path = latency
    ((_, markers, conn),) = _messages(path)["/cones"]
    assert conn.ext.offered_qos_profiles[0].durability == QosDurability.TRANSIENT_LOCAL
    cones_w = np.array(spec.scene.cones_w).reshape(-1, 3)
    assert len(markers.markers) == len(cones_w) >= 1
    marker_type = HUMBLE.types["visualization_msgs/msg/Marker"]
    n_points = 0
    for i, m in enumerate(markers.markers):
        assert (m.header.frame_id, m.ns, m.id) == ("map", "cones", i)
        assert m.type == marker_type.TRIANGLE_LIST and m.action == marker_type.ADD
        p = m.pose.position
        np.testing.assert_array_equal([p.x, p.y, p.z], cones_w[i])
        points = np.array([[q.x, q.y, q.z] for q in m.points])
        assert len(points) % 3 == 0 and len(m.colors) == len(points) > 0
        assert np.all(np.hypot(points[:, 0], points[:, 1]) <= footprint_radius_m() + 1e-9)
        assert points[:, 2].min() >= -1e-9
        assert points[:, 2].max() <= TRAFFIC_CONE.height_m + 1e-6
        n_points += len(points)
    assert n_points == 3 * len(keeper.scenery.cones_w.triangles)


def test_the_message_definitions_are_those_of_ros2_humble():
    """Each type's ``ros2msg`` text, dependencies included, is the one the rosbags ROS 2
    Humble type store generates as rosbag2 stores it; the schemas in the file are those."""
    for type_name in {*TOPICS.values(), "geometry_msgs/msg/PointStamped", IMU_TOPIC[1]}:
        assert msgdef(type_name) == HUMBLE.generate_msgdef(type_name, ros_version=2)[0]
    with pytest.raises(ValueError, match="no ROS 2 message definition"):
        msgdef("sensor_msgs/msg/NavSatFix")


def test_rerun_converts_the_bag(latency, tmp_path):
    """Rerun's own MCAP importer (``rerun mcap convert``, every channel through a ROS 2
    decoder, no raw fallback): the images it decodes are the rendered ones, its transforms the
    body poses (float32), its pinhole the camera's K."""
    from rerun.chunk import RrdReader

    _, keeper, _, _, path = latency
    rrd = tmp_path / "from-mcap.rrd"
    proc = subprocess.run(
        [RERUN, "mcap", "convert", path, "-o", rrd, "--disable-raw-fallback"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    reader = RrdReader(rrd)

    def column(entity: str, name: str) -> dict[int, object]:
        """``name``'s value at each message log time (ns) of ``entity``."""
        values = {}
        for chunk in reader.stream().filter(content=entity).to_chunks():
            batch = chunk.to_record_batch()
            if name in batch.schema.names:
                times = batch.column("message_log_time").cast(pa.int64()).to_pylist()
                values |= dict(zip(times, batch.column(name).to_pylist(), strict=True))
        return values

    index = {
        round(r.timing.stamp_cam_s * 1e9) + 1_000_000_000: i for i, r in enumerate(keeper.records)
    }
    buffers = column("/camera/image_raw", "Image:buffer")
    assert set(buffers) == set(index)
    for log_time, (buffer,) in buffers.items():
        assert bytes(buffer) == keeper.rgb[index[log_time]].tobytes()
    translations = column("/tf", "Transform3D:translation")
    assert set(translations) == set(index)
    assert set(map(tuple, column("/tf", "Transform3D:parent_frame").values())) == {("map",)}
    for log_time, (t,) in translations.items():
        T_w_b = keeper.records[index[log_time]].T_w_b
        np.testing.assert_allclose(t, T_w_b[:3, 3], rtol=1e-6, atol=1e-6)
    for (K_col_major,) in column("/camera/camera_info", "Pinhole:image_from_camera").values():
        np.testing.assert_allclose(np.reshape(K_col_major, (3, 3)).T, keeper.camera.K, rtol=1e-6)


def test_a_flight_that_slides_the_camera_puts_the_mount_on_tf(tmp_path):
    """``transform-composer`` moves the camera on the body: no /tf_static; each /tf holds the
    body pose and that tick's mount. Its camera clock has no offset: the stamps are the camera
    clock's, in nanoseconds, unshifted."""
    spec, keeper, _, _, path = _export("transform-composer", 0.6, tmp_path)
    assert spec.timing.camera_clock_offset_s == 0.0
    by_topic = _messages(path)
    assert "/tf_static" not in by_topic
    records = sorted(keeper.records, key=lambda r: r.timing.stamp_cam_s)
    assert len(by_topic["/tf"]) == len(records) > 1
    for (log_time, msg, _), r in zip(by_topic["/tf"], records, strict=True):
        body, mount = msg.transforms
        assert log_time == round(r.timing.stamp_cam_s * 1e9)
        assert (mount.header.frame_id, mount.child_frame_id) == (
            "base_link",
            "camera_optical_frame",
        )
        np.testing.assert_allclose(
            _pose(body.transform.translation, body.transform.rotation), r.T_w_b, atol=1e-9
        )
        np.testing.assert_allclose(
            _pose(mount.transform.translation, mount.transform.rotation), r.T_b_c, atol=1e-9
        )


def test_a_run_that_fails_leaves_no_file(tmp_path):
    """The run raises at its third tick: the runner aborts the exporter, which removes the
    file it had started; nothing is left in the staging directory."""
    spec = dataclasses.replace(builtin.load("latency"), duration_s=1.0)
    keeper = _Keeper(McapExporter(tmp_path, "latency"), fail_at_tick=2)
    with pytest.raises(RuntimeError, match="fails here"):
        run_scenario(spec, seed=1, observer=keeper)
    assert list(tmp_path.iterdir()) == []


def test_bad_images_are_refused(tmp_path, latency):
    """An image of the wrong shape or type is a ValueError naming it, before anything of the
    tick is written."""
    spec, keeper, *_ = latency
    exporter = McapExporter(tmp_path, "bad")
    exporter.start(spec, 1, keeper.camera, keeper.scenery)
    record = keeper.records[0]
    with pytest.raises(ValueError, match=r"rgb: expected a \(480, 640, 3\) uint8 image"):
        exporter.on_tick(record, keeper.rgb[0].astype(np.float32), None)
    with pytest.raises(ValueError, match="depth_m: expected a"):
        exporter.on_tick(record, keeper.rgb[0], keeper.depth[0][:10])
    exporter.abort()
    assert list(tmp_path.iterdir()) == []


def test_estimate_topics_are_ros_names():
    """A method's name as a ROS 2 topic: built-ins as they are, a user method's ``user:`` as a
    namespace, anything else a ROS name cannot hold as ``_``."""
    assert estimates_topic("depth_image") == "/estimates/depth_image"
    assert estimates_topic("user:my_fn") == "/estimates/user/my_fn"
    assert estimates_topic("user:2nd-try") == "/estimates/user/_2nd_try"


@pytest.mark.parametrize(
    ("encoding", "dtype", "channels", "stamp_ns"),
    [
        ("rgb8", np.uint8, 3, 1_020_000_000),
        ("16UC1", np.uint16, None, 33_333_333),
        ("mono8", np.uint8, None, 0),
        ("bgra8", np.uint8, 4, 1_700_000_000_123_456_789),
    ],
)
def test_an_image_message_is_the_generic_encoders_bytes(encoding, dtype, channels, stamp_ns):
    """``_image_cdr`` (the pixels copied once) makes the bytes mcap-ros2-support's own CDR
    encoder makes of the same ``sensor_msgs/Image``, whatever the padding the encoding's
    length leaves before ``step``; rosbags decodes them to the same pixels."""
    shape = (3, 5) if channels is None else (3, 5, channels)
    pixels = np.random.default_rng(0).integers(0, np.iinfo(dtype).max, shape, dtype=dtype)
    type_name = "sensor_msgs/msg/Image"
    encode = serialize_dynamic(type_name, msgdef(type_name))[type_name]
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    message = {
        "header": {"stamp": {"sec": sec, "nanosec": nanosec}, "frame_id": "camera_optical_frame"},
        "height": shape[0],
        "width": shape[1],
        "encoding": encoding,
        "is_bigendian": 0,
        "step": pixels.strides[0],
        "data": pixels.tobytes(),
    }
    data = _image_cdr(pixels, encoding, stamp_ns)
    assert data == encode(message)
    image = HUMBLE.deserialize_cdr(data, type_name)
    assert (image.height, image.width, image.encoding) == (shape[0], shape[1], encoding)
    got = np.frombuffer(image.data.tobytes(), dtype=np.dtype(dtype).newbyteorder("<"))
    np.testing.assert_array_equal(got.reshape(shape), pixels)


@pytest.mark.parametrize("stamp_ns", [0, 33_333_333, 1_020_000_000, 1_700_000_000_123_456_789])
def test_the_camera_info_encoded_once_and_restamped_is_the_generic_encoders(stamp_ns):
    """The camera info encoded once at stamp 0 and restamped (``_restamped``) is byte for byte
    what mcap-ros2-support's encoder makes of the message at ``stamp_ns``; rosbags reads the
    stamp and the intrinsics back."""
    camera = PinholeCamera.from_fovy(50.0, 640, 480)
    type_name = "sensor_msgs/msg/CameraInfo"
    encode = serialize_dynamic(type_name, msgdef(type_name))[type_name]
    data = _restamped(encode(_camera_info(camera, 0)), stamp_ns)
    assert data == encode(_camera_info(camera, stamp_ns))
    info = HUMBLE.deserialize_cdr(bytes(data), type_name)
    assert _ns(info.header.stamp) == stamp_ns
    np.testing.assert_array_equal(info.k.reshape(3, 3), camera.K)


def _bag(writer_class, compression: CompressionType) -> bytes:
    """A file of three channels' messages over several chunks, a metadata record between."""
    out = io.BytesIO()
    writer = (
        writer_class(out, compression)
        if writer_class is _LevelledWriter
        else writer_class(out, compression=compression)
    )
    writer.start(profile="ros2", library="test")
    schema = writer.register_schema("s", "ros2msg", b"int32 a")
    channels = [writer.register_channel(f"/t{i}", "cdr", schema) for i in range(3)]
    rng = np.random.default_rng(3)
    for i in range(40):
        if i == 17:
            writer.add_metadata("m", {"k": "v"})
        # Compressible bytes (a few values), 120 KB a message: several 1 MB chunks.
        data = rng.integers(0, 4, 120_000, dtype=np.uint8).tobytes()
        t_ns = 1_000_000 * (i * 7 % 40)  # out of order: each chunk's time range is a min/max
        writer.add_message(channels[i % 3], log_time=t_ns, data=data, publish_time=t_ns + 1)
    writer.finish()
    return out.getvalue()


def test_the_writer_compresses_the_chunks_at_its_level_and_writes_what_mcaps_does():
    """``_LevelledWriter`` (mcap's Writer, its chunk step replaced) writes what mcap's own
    Writer writes of the same messages but for the chunks' zstd bytes (and the offsets and
    sizes those move): each chunk is ``zstandard`` at ``ZSTD_LEVEL`` of the same records, its
    CRC zlib's; mcap's reader, checking every CRC, reads the same messages through the index."""
    ours = _bag(_LevelledWriter, CompressionType.ZSTD)
    theirs = _bag(McapWriter, CompressionType.ZSTD)
    assert ours != theirs
    ours_records = list(StreamReader(io.BytesIO(ours), emit_chunks=True).records)
    theirs_records = list(StreamReader(io.BytesIO(theirs), emit_chunks=True).records)
    assert [type(r) for r in ours_records] == [type(r) for r in theirs_records]
    # What holds a position in the file, or its size: those the chunks' sizes move.
    moved = {
        ChunkIndex: {"chunk_start_offset", "chunk_length", "compressed_size"},
        MetadataIndex: {"offset"},
        SummaryOffset: {"group_start"},
        Footer: {"summary_start", "summary_offset_start", "summary_crc"},
    }
    for mine, ref in zip(ours_records, theirs_records, strict=True):
        if isinstance(mine, Chunk):
            raw = zstandard.decompress(ref.data, max_output_size=ref.uncompressed_size)
            assert mine.data == zstandard.ZstdCompressor(level=ZSTD_LEVEL).compress(raw)
            assert mine.uncompressed_crc == zlib.crc32(raw) == ref.uncompressed_crc
            assert dataclasses.replace(mine, data=ref.data) == ref
            continue
        if isinstance(mine, ChunkIndex):
            # Each channel's message index at the same place after its chunk's record.
            def after_chunk(index: ChunkIndex) -> dict[int, int]:
                end = index.chunk_start_offset + index.chunk_length
                return {k: v - end for k, v in index.message_index_offsets.items()}

            assert after_chunk(mine) == after_chunk(ref)
            mine = dataclasses.replace(mine, message_index_offsets=ref.message_index_offsets)
        fixed = {k: v for k, v in vars(mine).items() if k not in moved.get(type(mine), ())}
        assert fixed == {k: v for k, v in vars(ref).items() if k not in moved.get(type(ref), ())}
    chunks = [r for r in ours_records if isinstance(r, Chunk)]
    indexes = [r for r in ours_records if isinstance(r, ChunkIndex)]
    assert len(chunks) == len(indexes) >= 3
    assert [i.compressed_size for i in indexes] == [len(c.data) for c in chunks]
    with io.BytesIO(ours) as f_ours, io.BytesIO(theirs) as f_theirs:
        read_ours = [
            (c.topic, m.log_time, m.publish_time, m.data)
            for _, c, m in make_reader(f_ours, validate_crcs=True).iter_messages(
                log_time_order=True
            )
        ]
        read_theirs = [
            (c.topic, m.log_time, m.publish_time, m.data)
            for _, c, m in make_reader(f_theirs).iter_messages(log_time_order=True)
        ]
    assert read_ours == read_theirs and len(read_ours) == 40


def test_another_compression_is_mcaps_own():
    """LZ4 (and no compression) go through mcap's own chunk step: the same bytes."""
    for compression in (CompressionType.LZ4, CompressionType.NONE):
        assert _bag(_LevelledWriter, compression) == _bag(McapWriter, compression)
