"""ROS 2 for simseam without a ROS installation: DDS (Cyclone), MCAP recording, Foxglove.

- ``msgs``: ROS 2 message types as Cyclone IDL structs (byte-identical CDR).
- ``convert``: HAL readings -> messages, commands -> HAL actions (no DDS).
- ``dds``: participant, ROS 2 topic/QoS conventions, loopback-only default config.
- ``record``: MCAP file and Foxglove live server sinks (ros2msg schemas, CDR).
- ``bridge``: the real-time paced loop behind ``simseam deploy``.

Needs ``pip install 'simseam[ros2]'`` (cyclonedds, rosbags, mcap, foxglove-sdk).
"""
