"""Logs written for other tools: a ROS 2 bag (:func:`export_ros2`)."""

from acq.export.ros2 import Ros2Report, export_ros2

__all__ = ["Ros2Report", "export_ros2"]
