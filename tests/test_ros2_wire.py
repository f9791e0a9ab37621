"""The project's rmw_zenoh encoder (services.ros2) against independent implementations.

Type hashes, data keys, graph tokens and attachments against zenoh-ros2-sdk,
CDR bytes against rosbags (the serializer zenoh-ros2-sdk uses), both from the
registry; nothing here is computed by the project's own code on both sides.
"""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.ros2 import msgs
from services.ros2.graph import (
    Attachment,
    endpoint_token,
    node_token,
    qos_string,
    topic_key,
)
from services.ros2.sdk import SDK_TYPES, use_local_definitions
from tests import HANG

sdk = pytest.importorskip("zenoh_ros2_sdk")
rosbags_typesys = pytest.importorskip("rosbags.typesys")
from zenoh_ros2_sdk import entity, keyexpr, utils  # noqa: E402
from zenoh_ros2_sdk.attachment import Attachment as SdkAttachment  # noqa: E402
from zenoh_ros2_sdk.qos import QosProfile  # noqa: E402

STORE = rosbags_typesys.get_typestore(rosbags_typesys.Stores.ROS2_JAZZY)
T = STORE.types


@pytest.fixture(scope="module")
def registry(tmp_path_factory):
    folder = use_local_definitions(tmp_path_factory.mktemp("msgs"))
    return sdk.get_registry(str(folder))


def _sdk_hash(registry, name: str) -> str:
    text = registry.get_msg_file_path(name).read_text()
    deps = utils.load_dependencies_recursive(name, text, registry)
    return utils.get_type_hash(name, msg_definition=text, dependencies=deps)


@pytest.mark.parametrize("name", SDK_TYPES)
def test_type_hashes_and_keys_equal_the_independent_ones(registry, name):
    mine = msgs.type_hash(name)
    assert mine == STORE.hash_rihs01(name) == _sdk_hash(registry, name)
    assert msgs.dds_type_name(name) == utils.ros2_to_dds_type(name)
    for domain, topic in ((0, "/robot1/cmd_vel"), (7, "/fleet/robot_12/odom")):
        assert topic_key(domain, topic, name) == keyexpr.topic_keyexpr(
            domain, topic, utils.ros2_to_dds_type(name), mine)


def test_graph_tokens_equal_the_independent_ones():
    zid = "24d8897d0a7519a6cebe83138c21ba08"
    node = entity.NodeEntity(domain_id=3, session_id=zid, node_id=0,
                             node_name="sqpmpc_robot1", namespace="/robot1")
    assert node_token(3, zid, 0, "/robot1", "sqpmpc_robot1") == keyexpr.node_liveliness_keyexpr(
        node)
    name = "geometry_msgs/msg/Twist"
    for kind, ekind in (("MP", entity.EntityKind.PUBLISHER),
                        ("MS", entity.EntityKind.SUBSCRIPTION)):
        ep = entity.EndpointEntity(node=node, entity_id=4, kind=ekind, name="/robot1/cmd_vel",
                                   dds_type_name=utils.ros2_to_dds_type(name),
                                   type_hash=STORE.hash_rihs01(name), qos=QosProfile().encode())
        assert endpoint_token(3, zid, 0, 4, kind, "/robot1", "sqpmpc_robot1",
                              "/robot1/cmd_vel", name) == keyexpr.endpoint_liveliness_keyexpr(ep)
    assert qos_string() == QosProfile().encode()
    assert QosProfile.decode(qos_string(depth=3)).history_depth == 3


def test_attachments_read_both_ways():
    gid = bytes(range(16))
    mine = Attachment(7, 1_700_000_000_123_456_789, gid)
    raw = mine.to_bytes()
    assert len(raw) == 33
    theirs = SdkAttachment.from_bytes(raw)
    assert (theirs.sequence_id, theirs.timestamp_ns, theirs.gid) == (7, mine.timestamp_ns, gid)
    assert Attachment.from_bytes(SdkAttachment(9, 5, gid).to_bytes()) == Attachment(9, 5, gid)
    with pytest.raises(ValueError, match="33 bytes"):
        Attachment.from_bytes(raw[:-1])


# ------------------------------------------------------------------------------- CDR
def _theirs_twist(lin, ang):
    return T["geometry_msgs/msg/Twist"](linear=T["geometry_msgs/msg/Vector3"](*lin),
                                        angular=T["geometry_msgs/msg/Vector3"](*ang))


def _theirs_header(sec, nsec, frame):
    return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec, nsec),
                                    frame_id=frame)


def _theirs_pose(x, y, psi):
    q = msgs.yaw_quaternion(psi)
    return T["geometry_msgs/msg/Pose"](T["geometry_msgs/msg/Point"](x, y, 0.0),
                                       T["geometry_msgs/msg/Quaternion"](q.x, q.y, q.z, q.w))


def _mine_pose(x, y, psi):
    return msgs.Pose(msgs.Point(x, y, 0.0), msgs.yaw_quaternion(psi))


finite = st.floats(-1e6, 1e6, allow_nan=False)
frames = st.text(alphabet="abcdefghij_/0123456789", max_size=13)


@settings(max_examples=60, deadline=None)
@given(lin=st.tuples(finite, finite, finite), ang=st.tuples(finite, finite, finite),
       sec=st.integers(0, 2**31 - 1), nsec=st.integers(0, 999_999_999), frame=frames)
def test_twist_and_twist_stamped_bytes_equal_rosbags(lin, ang, sec, nsec, frame):
    mine = msgs.Twist(msgs.Vector3(*lin), msgs.Vector3(*ang))
    data = msgs.serialize(mine)
    assert data == bytes(STORE.serialize_cdr(_theirs_twist(lin, ang), "geometry_msgs/msg/Twist"))
    assert len(data) == 52 and msgs.deserialize(data, "geometry_msgs/msg/Twist") == mine
    stamped = msgs.TwistStamped(msgs.Header(msgs.Time(sec, nsec), frame), mine)
    theirs = T["geometry_msgs/msg/TwistStamped"](_theirs_header(sec, nsec, frame),
                                                 _theirs_twist(lin, ang))
    raw = bytes(STORE.serialize_cdr(theirs, "geometry_msgs/msg/TwistStamped"))
    assert msgs.serialize(stamped) == raw
    assert msgs.deserialize(raw, "geometry_msgs/msg/TwistStamped") == stamped


@settings(max_examples=40, deadline=None)
@given(pose=st.tuples(finite, finite, st.floats(-math.pi, math.pi)), frame=frames,
       child=frames, cov=st.lists(finite, min_size=36, max_size=36), v=finite, w=finite)
def test_odometry_bytes_equal_rosbags(pose, frame, child, cov, v, w):
    mine = msgs.Odometry(msgs.Header(msgs.Time(12, 345), frame), child,
                         msgs.PoseWithCovariance(_mine_pose(*pose), tuple(cov)),
                         msgs.TwistWithCovariance(
                             msgs.Twist(msgs.Vector3(v), msgs.Vector3(0.0, 0.0, w)),
                             tuple(reversed(cov))))
    theirs = T["nav_msgs/msg/Odometry"](
        _theirs_header(12, 345, frame), child,
        T["geometry_msgs/msg/PoseWithCovariance"](_theirs_pose(*pose), np.array(cov)),
        T["geometry_msgs/msg/TwistWithCovariance"](_theirs_twist((v, 0, 0), (0, 0, w)),
                                                   np.array(cov[::-1])))
    raw = bytes(STORE.serialize_cdr(theirs, "nav_msgs/msg/Odometry"))
    assert msgs.serialize(mine) == raw
    assert msgs.deserialize(raw, "nav_msgs/msg/Odometry") == mine


@settings(max_examples=30, deadline=None)
@given(frame=frames, states=st.lists(st.tuples(finite, finite, st.floats(-3.0, 3.0)),
                                     max_size=10), frames_=st.lists(frames, min_size=10,
                                                                    max_size=10))
def test_path_bytes_equal_rosbags(frame, states, frames_):
    mine = msgs.Path(msgs.Header(msgs.Time(1, 2), frame), tuple(
        msgs.PoseStamped(msgs.Header(msgs.Time(i, 7 * i), frames_[i]), _mine_pose(*s))
        for i, s in enumerate(states)))
    theirs = T["nav_msgs/msg/Path"](_theirs_header(1, 2, frame), [
        T["geometry_msgs/msg/PoseStamped"](_theirs_header(i, 7 * i, frames_[i]),
                                           _theirs_pose(*s)) for i, s in enumerate(states)])
    raw = bytes(STORE.serialize_cdr(theirs, "nav_msgs/msg/Path"))
    assert msgs.serialize(mine) == raw
    assert msgs.deserialize(raw, "nav_msgs/msg/Path") == mine


def test_bad_cdr_is_one_clear_error():
    twist = msgs.serialize(msgs.Twist())
    with pytest.raises(msgs.CdrError, match="truncated"):
        msgs.deserialize(twist[:-8], "geometry_msgs/msg/Twist")
    with pytest.raises(msgs.CdrError, match="little-endian"):
        msgs.deserialize(b"\x00\x00\x00\x00" + twist[4:], "geometry_msgs/msg/Twist")
    with pytest.raises(msgs.CdrError, match="left after"):
        msgs.deserialize(twist + bytes(8), "geometry_msgs/msg/Twist")
    huge = b"\x00\x01\x00\x00" + bytes(4) + bytes(8) + struct.pack("<I", 1 << 30)
    with pytest.raises(msgs.CdrError):
        msgs.deserialize(huge, "nav_msgs/msg/Path")
    with pytest.raises(ValueError, match="unknown message type"):
        msgs.type_hash("nav_msgs/msg/Nothing")


def test_an_independent_node_reads_what_a_node_of_this_encoder_sends(tmp_path):
    """Over a router on loopback: TwistStamped and Path from services.ros2.graph to
    zenoh-ros2-sdk subscribers, Odometry the other way, and the SDK's graph query."""
    import time

    import zenoh

    from services.ros2.graph import Ros2Node
    from services.testing import free_ports, start_service, stop_processes
    from services.transport import make_config

    port = free_ports(1)[0]
    router = start_service("router", ["--listen", f"tcp/127.0.0.1:{port}"], tmp_path)
    use_local_definitions(tmp_path / "msgs")
    sdk_session = session = None
    try:
        sdk_session = sdk.ZenohSession.get_instance("127.0.0.1", port)
        got: dict[str, list] = {"cmd": [], "plan": [], "odom": []}
        subs = [sdk.ROS2Subscriber("/r7/cmd_vel", "geometry_msgs/msg/TwistStamped",
                                   callback=got["cmd"].append, router_port=port, domain_id=5),
                sdk.ROS2Subscriber("/r7/plan", "nav_msgs/msg/Path",
                                   callback=got["plan"].append, router_port=port, domain_id=5)]
        odom_pub = sdk.ROS2Publisher("/r7/odom", "nav_msgs/msg/Odometry", router_port=port,
                                     domain_id=5, node_name="base")
        session = zenoh.open(make_config((), [f"tcp/127.0.0.1:{port}"], "client"))
        node = Ros2Node(session, "sqpmpc_robot7", "/r7", domain=5)
        node.subscribe("odom", "nav_msgs/msg/Odometry", got["odom"].append)
        cmd = node.publisher("cmd_vel", "geometry_msgs/msg/TwistStamped")
        path = node.publisher("plan", "nav_msgs/msg/Path")
        sent_cmd = msgs.TwistStamped(msgs.Header(msgs.Time(3, 4), "base_link"),
                                     msgs.Twist(msgs.Vector3(0.25), msgs.Vector3(0, 0, -0.5)))
        sent_path = msgs.Path(msgs.Header(msgs.Time(3, 4), "odom"), tuple(
            msgs.PoseStamped(msgs.Header(msgs.Time(3 + i, 0), "odom"), _mine_pose(i, -i, 0.1))
            for i in range(9)))
        deadline = time.time() + HANG
        while time.time() < deadline and not all(got.values()):
            cmd.publish(sent_cmd)
            path.publish(sent_path)
            odom_pub.publish(header=T["std_msgs/msg/Header"](
                stamp=T["builtin_interfaces/msg/Time"](1, 2), frame_id="odom"),
                child_frame_id="base_link",
                pose=T["geometry_msgs/msg/PoseWithCovariance"](_theirs_pose(1.0, 2.0, 0.5),
                                                               np.zeros(36)),
                twist=T["geometry_msgs/msg/TwistWithCovariance"](
                    _theirs_twist((0.3, 0, 0), (0, 0, 0.2)), np.zeros(36)))
            time.sleep(0.2)
        while True:  # asked again while a busy machine answers a query short
            info = sdk.get_topic_info("/r7/plan", domain_id=5, router_port=port, timeout=1.0,
                                      verbose=True)
            topics = dict(sdk.get_topic_names_and_types(domain_id=5, router_port=port,
                                                        timeout=1.0))
            if ("/r7/cmd_vel" in topics and any(e.node_name == "sqpmpc_robot7"
                                                for e in info.publishers)) \
                    or time.time() > deadline:
                break
            time.sleep(0.2)
        for ep in [*subs, odom_pub]:
            ep.close()
        node.close()
    finally:
        if session is not None:
            session.close()
        if sdk_session is not None:
            sdk_session.close()
        stop_processes([router])
    c = got["cmd"][-1]
    assert (c.header.frame_id, c.twist.linear.x, c.twist.angular.z) == ("base_link", 0.25, -0.5)
    p = got["plan"][-1]
    assert len(p.poses) == 9 and p.poses[8].pose.position.x == 8.0
    o = got["odom"][-1]
    assert o.attachment is not None and o.attachment.sequence >= 0
    assert math.isclose(msgs.quaternion_yaw(o.msg.pose.pose.orientation), 0.5)
    assert (o.msg.twist.twist.linear.x, o.msg.twist.twist.angular.z) == (0.3, 0.2)
    assert topics["/r7/cmd_vel"] == ["geometry_msgs/msg/TwistStamped"]
    assert any(e.node_name == "sqpmpc_robot7" and e.node_namespace == "/r7"
               for e in info.publishers)
