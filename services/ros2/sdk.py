"""Set up the independent rmw_zenoh implementation (zenoh-ros2-sdk) offline.

zenoh-ros2-sdk reads ``.msg`` files from a message folder and, for a type it
does not find there, tries to clone the ROS 2 interface repositories at run
time (which fails offline). :func:`use_local_definitions` writes the ROS 2
Jazzy definitions shipped by ``rosbags`` (its type store, another independent
package) as ``.msg`` files into a folder and points the SDK's registry at it
before its first use. Used by the simulated fleet and the tests only: the
robot service speaks the format through :mod:`services.ros2.graph`.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["SDK_TYPES", "use_local_definitions"]

SDK_TYPES = ("nav_msgs/msg/Odometry", "geometry_msgs/msg/Twist",
             "geometry_msgs/msg/TwistStamped", "nav_msgs/msg/Path")
"""The message types the fleet and the tests use (and the ones they refer to)."""


def use_local_definitions(folder: Path) -> Path:
    """Write the Jazzy ``.msg`` files of :data:`SDK_TYPES` and their dependencies into
    ``folder`` and make it zenoh-ros2-sdk's message registry; returns ``folder``.

    Call it before the SDK's session of a router is opened (once per session).
    """
    from rosbags.typesys import Stores, get_typestore
    from zenoh_ros2_sdk import message_registry

    store = get_typestore(Stores.ROS2_JAZZY)
    todo, done = list(SDK_TYPES), set()
    while todo:
        name = todo.pop()
        if name in done:
            continue
        done.add(name)
        text = store.generate_msgdef(name, ros_version=2)[0].split("=" * 80)[0]
        pkg, kind, typ = name.split("/")
        path = folder / pkg / kind / f"{typ}.msg"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
        for _, desc in store.fielddefs[name][1]:
            ref = _nested(desc)
            if ref is not None:
                todo.append(ref)
    # a fresh registry: the SDK's global one remembers the types loaded into the store of
    # a session closed since (a later session's store would lack them)
    message_registry._registry = message_registry.MessageRegistry(str(folder))
    return folder


def _nested(desc: tuple) -> str | None:
    """The type a rosbags field description refers to, if it is a message."""
    from rosbags.interfaces import Nodetype

    kind, rest = desc
    if kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
        kind, rest = rest[0]
    return rest if kind == Nodetype.NAME else None
