"""sgreg play / record / bw on a small bag written here: real processes over DDS on loopback."""
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.rosbag2 import CompressionFormat, CompressionMode, Reader, StoragePlugin, Writer

import sgreg_msgs.msg as msgs
from sgreg_cli.bag_types import typestore

from .samples import coarse_graph, instance_map

SGREG = [sys.executable, "-m", "sgreg_cli.main"]


def write_bag(path, corrupt_index=None, n=6, compress=False):
    """n InstanceMaps and n CoarseGraphs, 0.1 s apart; optionally one CoarseGraph truncated,
    optionally in zstd chunks (as make-bag writes)."""
    rng = np.random.default_rng(1)
    sent = {"/a/mapping/instances": [], "/b/sgreg/coarse": []}
    store = typestore()
    writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
    if compress:
        writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    with writer as w:
        ci = w.add_connection("/a/mapping/instances", "sgreg_msgs/msg/InstanceMap", typestore=store)
        cc = w.add_connection("/b/sgreg/coarse", "sgreg_msgs/msg/CoarseGraph", typestore=store)
        for i in range(n):
            m = instance_map(rng, n_points=500)
            m.sequence = i
            g = coarse_graph(rng, n_nodes=10, dim=16)
            g.sequence = i
            t = 10**9 + i * 10**8
            w.write(ci, t, serialize_message(m))
            raw = serialize_message(g)
            if i == corrupt_index:
                raw = raw[: len(raw) // 3]
            else:
                sent["/b/sgreg/coarse"].append(g)
            w.write(cc, t + 1, raw)
            sent["/a/mapping/instances"].append(m)
    return sent


def chunk_crcs(bag):
    """The CRC-32 each chunk of the bag's MCAP file carries (0: none), read by the mcap package."""
    from mcap.records import Chunk
    from mcap.stream_reader import StreamReader

    with open(next(bag.glob("*.mcap")), "rb") as f:
        return [r.uncompressed_crc for r in StreamReader(f, emit_chunks=True).records if isinstance(r, Chunk)]


def flip_bytes(bag, at=0.5, n=32):
    """Damage n bytes of the bag's MCAP file from a fraction `at` of it (inside the chunk of a
    write_bag bag) or from the first occurrence of the bytes `at`."""
    mcap = next(bag.glob("*.mcap"))
    b = bytearray(mcap.read_bytes())
    i = b.index(at) if isinstance(at, bytes) else int(len(b) * at)
    b[i:i + n] = bytes(x ^ 0xFF for x in b[i:i + n])
    mcap.write_bytes(b)


def read_bag(path):
    got = {}
    with Reader(path) as r:
        for conn, _, raw in r.messages():
            cls = getattr(msgs, conn.msgtype.rsplit("/", 1)[-1])
            got.setdefault(conn.topic, []).append(deserialize_message(bytes(raw), cls))
    return got


def test_play_into_record_reproduces_the_bag(tmp_path):
    src = tmp_path / "src"
    sent = write_bag(src)
    out = tmp_path / "rec"
    rec = subprocess.Popen(SGREG + ["record", "/a/mapping/instances", "/b/sgreg/coarse",
                                    "--out", str(out), "--duration", "14"],
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    first = rec.stdout.readline()
    assert first.startswith("recorder ready"), first
    play = subprocess.run(SGREG + ["play", str(src), "--rate", "0.5", "--delay", "1", "--wait-subscribers", "30"], capture_output=True,
                          text=True, timeout=60)
    rec_out = first + rec.communicate(timeout=60)[0]
    assert play.returncode == 0, play.stderr
    assert "played 12 messages" in play.stdout
    assert rec.returncode == 0, rec_out
    got = read_bag(out)
    # the publishers' QoS is in the bag, for `ros2 bag play` (transient local for coarse graphs)
    from rosbags.interfaces import QosDurability
    with Reader(out) as r:
        offered = {c.topic: c.ext.offered_qos_profiles for c in r.connections}
    assert [q.durability for q in offered["/b/sgreg/coarse"]] == [QosDurability.TRANSIENT_LOCAL]
    assert [q.durability for q in offered["/a/mapping/instances"]] == [QosDurability.VOLATILE]
    assert all(chunk_crcs(out)), "the recorder leaves chunks without a checksum"
    # transient-local coarse may be delivered once more on late discovery; compare content
    for topic, messages in sent.items():
        received = [m for m in got.get(topic, [])]
        assert [m.sequence for m in received][-len(messages):] == [m.sequence for m in messages], topic
        assert all(a == b for a, b in zip(received[-len(messages):], messages)), topic


def _play_stopped(src, sig, after: float, delay: str = "0"):
    """(exit code, stdout, stderr) of `sgreg play` sent `sig` `after` seconds into playing."""
    import time

    play = subprocess.Popen(SGREG + ["play", str(src), "--delay", delay], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    assert play.stderr.readline().startswith("sgreg play: playing")    # rclpy's handlers are in
    time.sleep(after)
    play.send_signal(sig)
    out, err = play.communicate(timeout=20)
    assert "Traceback" not in err, err
    return play.returncode, out, err


def test_play_ends_cleanly_on_sigterm(tmp_path):
    import signal

    src = tmp_path / "long"
    write_bag(src, n=300)           # 30 s of messages
    code, out, err = _play_stopped(src, signal.SIGTERM, 2.0)
    assert code == 0, err
    assert out.startswith("stopped by shutdown: played "), out     # what was played is said
    # Ctrl-C: the same summary, and the shell's code for it
    code, out, err = _play_stopped(src, signal.SIGINT, 2.0)
    assert code == 130 and out.startswith("stopped by Ctrl-C: played "), (out, err)
    # Ctrl-C while play still waits for its start (--delay): the same, with nothing played
    code, out, err = _play_stopped(src, signal.SIGINT, 1.0, delay="30")
    assert code == 130 and out.startswith("stopped by Ctrl-C: played 0 messages"), (out, err)


def test_corrupted_message_is_reported_and_the_rest_plays(tmp_path):
    src = tmp_path / "bad"
    write_bag(src, corrupt_index=2)
    play = subprocess.run(SGREG + ["play", str(src), "--rate", "4"], capture_output=True, text=True, timeout=60)
    assert play.returncode == 0, play.stderr
    assert "played 11 messages" in play.stdout
    assert "1 corrupted messages skipped" in play.stdout
    assert "corrupted" in play.stderr and "/b/sgreg/coarse" in play.stderr


def test_bw_of_a_bag(tmp_path):
    src = tmp_path / "src"
    sent = write_bag(src)
    out = subprocess.run(SGREG + ["bw", "--bag", str(src)], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    sizes = [len(serialize_message(m)) for m in sent["/b/sgreg/coarse"]]
    line = next(l for l in out.stdout.splitlines() if l.startswith("/b/sgreg/coarse"))
    assert line.split()[1] == "6"
    total_kb = sum(sizes) / 1e3
    assert f"{total_kb:.2f} kB" in line
    # a name typed without its leading slash is the same topic, as ros2 resolves it
    out = subprocess.run(SGREG + ["bw", "--bag", str(src), "b/sgreg/coarse"], capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0, out.stderr
    assert line.split() in [l.split() for l in out.stdout.splitlines()], out.stdout


def test_bw_of_a_bag_without_messages_and_bad_live_options(tmp_path):
    empty = tmp_path / "empty"
    write_bag(empty, n=0)
    out = subprocess.run(SGREG + ["bw", "--bag", str(empty)], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and out.stdout.splitlines() == [f"bag {empty}: 0.0 s", "(no messages)"], out
    for bad in (["--window", "0"], ["--window", "inf"], ["--duration", "-1"], ["--duration", "nan"]):
        out = subprocess.run(SGREG + ["bw", *bad], capture_output=True, text=True, timeout=60)
        assert out.returncode == 2 and out.stderr.startswith("sgreg bw: --window must be") \
            and out.stderr.count("\n") == 1, (bad, out.stderr)


def test_play_refuses_bad_numbers_before_it_starts(capsys):
    from sgreg_cli.main import main

    bag = str(Path(__file__).resolve().parents[2] / "bags" / "apartment_opposite")
    for flag, value in (("--rate", "nan"), ("--rate", "0"), ("--delay", "nan"), ("--delay", "inf"),
                        ("--wait-subscribers", "-1"), ("--clock", "-5"), ("--clock", "nan")):
        assert main(["play", bag, flag, value]) == 2, (flag, value)
        err = capsys.readouterr().err
        assert err.startswith(f"sgreg play: {flag} must be") and err.count("\n") == 1, err


def test_play_refuses_a_directory_that_is_not_a_bag(tmp_path):
    out = subprocess.run(SGREG + ["play", str(tmp_path)], capture_output=True, text=True, timeout=60)
    assert out.returncode == 2
    assert "not a rosbag2 directory" in out.stderr


def test_bw_and_play_refuse_topics_the_bag_lacks(tmp_path):
    # rosbags reads an empty selection of topics as "all of them"
    src = tmp_path / "src"
    write_bag(src)
    for argv in (["bw", "--bag", str(src), "/does/not/exist"],
                 ["play", str(src), "--delay", "0", "--topics", "/does/not/exist"],
                 ["play", str(src), "--delay", "0", "--topics"]):
        out = subprocess.run(SGREG + argv, capture_output=True, text=True, timeout=60)
        assert out.returncode == 2, (argv, out.stdout, out.stderr)
        assert "has none of the topics" in out.stderr and "/b/sgreg/coarse" in out.stderr, argv
        assert "played" not in out.stdout and "/a/mapping" not in out.stdout


def test_a_damaged_chunk_is_a_clear_error(tmp_path):
    from sgreg_cli.bags import BagError, instance_maps_in_bag

    src = tmp_path / "src"
    write_bag(src, compress=True)
    flip_bytes(src, at=b"\x28\xb5\x2f\xfd")     # the zstd frame's start: its random points hide damage elsewhere
    for argv in (["bw", "--bag", str(src)], ["play", str(src), "--delay", "0"]):
        out = subprocess.run(SGREG + argv, capture_output=True, text=True, timeout=60)
        assert out.returncode == 2 and "is damaged" in out.stderr, (argv, out.stderr)
        assert "Traceback" not in out.stderr
    with pytest.raises(BagError, match="is damaged"):
        instance_maps_in_bag(src)


def test_sealed_chunks_turn_flipped_bytes_into_an_error(tmp_path):
    from sgreg_cli.bags import seal_chunks

    src = tmp_path / "src"
    sent = write_bag(src)                   # uncompressed, as the recorder writes
    assert chunk_crcs(src) == [0]           # rosbags' writer leaves the checksum out
    seal_chunks(src)
    assert all(chunk_crcs(src)) and len(read_bag(src)["/b/sgreg/coarse"]) == len(sent["/b/sgreg/coarse"])
    flip_bytes(src)
    out = subprocess.run(SGREG + ["bw", "--bag", str(src)], capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "checksum" in out.stderr, out.stderr


def test_play_skips_maps_whose_points_are_not_finite_or_absurd(tmp_path):
    from sgreg_cli.bags import instance_maps_in_bag
    from sgreg_ros.pointcloud import pack_xyz_id

    src, rng = tmp_path / "src", np.random.default_rng(2)
    with Writer(src, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conn = w.add_connection("/a/mapping/instances", "sgreg_msgs/msg/InstanceMap", typestore=typestore())
        for i, bad in enumerate([None, np.nan, 2e38, None]):
            m = instance_map(rng, n_points=200)
            if bad is not None:                 # what flipped bytes in a map decode to
                pts = rng.normal(size=(200, 3))
                pts[7] = bad
                m.points = pack_xyz_id(pts, rng.choice(m.instance_ids, 200), "instance", frame_id="a/map")
            w.write(conn, 10**9 + i * 10**8, serialize_message(m))
    assert len(instance_maps_in_bag(src)) == 2
    play = subprocess.run(SGREG + ["play", str(src), "--delay", "0"], capture_output=True, text=True, timeout=60)
    assert play.returncode == 0, play.stderr
    assert "played 2 messages" in play.stdout and "2 corrupted messages skipped: #1 on" in play.stdout
    assert "NaN or infinite" in play.stderr and "m from the origin" in play.stderr


def test_record_refuses_an_uncreatable_folder_and_a_negative_duration(tmp_path):
    (tmp_path / "file").write_text("")
    for argv, why in ((["--out", str(tmp_path / "file" / "bag"), "--duration", "1"], "cannot create bag"),
                      (["--out", str(tmp_path / "bag"), "--duration", "-1"], "--duration must be >= 0")):
        out = subprocess.run(SGREG + ["record", "/x"] + argv, capture_output=True, text=True, timeout=30)
        assert out.returncode == 2 and why in out.stderr and "Traceback" not in out.stderr, out.stderr


def write_odd_bag(path):
    """A bag as other tools record them: its own /clock (sim time from 0), markers recorded
    transient-local, a topic of a message type not installed here, a topic that starts 1 s
    into the bag, and a burst of 200 messages in its first half second."""
    from rosbags.typesys import get_types_from_msg
    from rosgraph_msgs.msg import Clock
    from std_msgs.msg import String
    from visualization_msgs.msg import MarkerArray

    from sgreg_cli.bags import offered_qos
    from sgreg_ros import qos

    store = typestore()
    store.register(get_types_from_msg("int32 v", "foo_msgs/msg/Bar"))
    t0 = 10**9
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        clock = w.add_connection("/clock", "rosgraph_msgs/msg/Clock", typestore=store)
        markers = w.add_connection("/x/sgreg/markers", "visualization_msgs/msg/MarkerArray", typestore=store,
                                   offered_qos_profiles=[offered_qos(qos.VIEW)])
        foo = w.add_connection("/foo", "foo_msgs/msg/Bar", typestore=store)
        late = w.add_connection("/late", "std_msgs/msg/String", typestore=store)
        burst = w.add_connection("/burst", "std_msgs/msg/String", typestore=store)
        for i in range(200):        # every 2.5 ms: /clock must still go out at its own rate
            w.write(burst, t0 + i * 25 * 10**5, serialize_message(String(data="b")))
        for i in range(6):
            c = Clock()
            c.clock.nanosec = i * 10**8
            w.write(clock, t0 + i * 10**8, serialize_message(c))
        for i in range(3):
            w.write(markers, t0 + i * 10**8, serialize_message(MarkerArray()))
            w.write(foo, t0 + i * 10**8, store.serialize_cdr(store.types["foo_msgs/msg/Bar"](v=i), "foo_msgs/msg/Bar"))
        w.write(late, t0 + 10**9, serialize_message(String(data="late")))


def test_play_keeps_one_clock_the_recorded_qos_and_the_bags_timeline(tmp_path):
    """As `ros2 bag play`: with --clock the bag's own /clock is not played too (time would go
    back and forth), topics are offered with the QoS they were recorded with (RViz subscribes
    to markers transient-local), a topic of a type not installed is left out with a line, and
    a topic selected with --topics keeps its place on the bag's timeline."""
    import time

    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rosgraph_msgs.msg import Clock
    from std_msgs.msg import String
    from visualization_msgs.msg import MarkerArray

    from sgreg_ros import qos

    bag = tmp_path / "odd"
    write_odd_bag(bag)
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    try:
        node = rclpy.create_node("odd_listener", context=ctx)
        clocks, markers = [], []
        node.create_subscription(Clock, "/clock", lambda m: clocks.append(m.clock.sec + m.clock.nanosec * 1e-9), 100)
        node.create_subscription(MarkerArray, "/x/sgreg/markers", markers.append, qos.VIEW)
        for topic in ("/late", "/burst"):       # a subscriber on every topic: no wait for one
            node.create_subscription(String, topic, lambda m: None, 10)
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(node)

        def run(*args):
            play = subprocess.Popen(SGREG + ["play", str(bag), "--clock", "20", "--wait-subscribers", "20",
                                             *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            deadline = time.monotonic() + 60
            while play.poll() is None and time.monotonic() < deadline:
                ex.spin_once(timeout_sec=0.05)
            for _ in range(20):
                ex.spin_once(timeout_sec=0.05)
            out, err = play.communicate(timeout=10)
            assert play.returncode == 0, err
            return err

        err = run("--delay", "0.5")
        assert "not playing /foo: message type foo_msgs/msg/Bar is not available" in err, err
        assert len(markers) == 3, f"a transient-local subscriber got {len(markers)} of 3 markers"
        assert clocks and all(b >= a for a, b in zip(clocks, clocks[1:])), "time went back on /clock"
        assert min(clocks) >= 1.0, "the bag's own /clock (sim time from 0) was played beside --clock"
        assert len(clocks) < 20 * 4, f"{len(clocks)} /clock messages in about 1.5 s at 20 Hz"
        # only the late topic: it still comes 1 s into the bag, /clock running through the gap
        clocks.clear()
        run("--topics", "/late", "--delay", "0.2")
        assert any(1.1 < c < 1.9 for c in clocks), f"/clock jumped over the bag's first second: {clocks}"
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)


def test_bw_of_a_one_message_bag_gives_no_rate(tmp_path):
    one = tmp_path / "one"
    write_bag(one, n=1)
    out = subprocess.run(SGREG + ["bw", "--bag", str(one)], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    line = next(l for l in out.stdout.splitlines() if l.startswith("/b/sgreg/coarse"))
    assert line.split()[2] == "-", out.stdout       # not 997000.00 MB/s


def test_live_bw_hears_a_best_effort_topic_at_its_rate_from_the_first_seconds():
    """As `ros2 topic bw`: a best-effort publisher is heard (a reliable reader hears nothing of
    it), and before a whole window has passed the rate divides by the time watched: 20 messages
    of about 1 kB a second read about 20 kB/s, not 6 kB/s of a 10 s window."""
    import re
    import time

    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import qos_profile_sensor_data
    from std_msgs.msg import String

    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    try:
        node = rclpy.create_node("be_talker", context=ctx)
        pub = node.create_publisher(String, "/x/sgreg/chatter", qos_profile_sensor_data)
        msg = String(data="x" * 1000)
        node.create_timer(0.05, lambda: pub.publish(msg))
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(node)
        bw = subprocess.Popen(SGREG + ["bw", "/x/sgreg/chatter", "--duration", "5", "--window", "10"],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 60
        while bw.poll() is None and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.01)
        out, err = bw.communicate(timeout=10)
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)
    assert bw.returncode == 0, err
    last = [l for l in out.splitlines() if l.startswith("/x/sgreg/chatter")][-1]
    rate = re.search(r"([\d.]+) kB/s", last)
    assert rate and 12.0 < float(rate.group(1)) < 30.0, out
