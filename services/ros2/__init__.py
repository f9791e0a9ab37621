"""ROS 2 robots over Zenoh: rmw_zenoh's wire format and the robot service that drives them.

- :mod:`services.ros2.msgs`: the message types, their RIHS01 type hashes, CDR;
- :mod:`services.ros2.graph`: data keys, attachments, liveliness tokens, a node;
- :mod:`services.ros2.robot`: ``sqpmpc robot --ros2`` (CONTRACT 4);
- :mod:`services.ros2.simfleet`: simulated ROS 2 robots written with an independent
  implementation of the format (zenoh-ros2-sdk), for tests and the demo;
- :mod:`services.ros2.demo`: the fleet with one controller process per robot.
"""

__all__: list[str] = []
