"""flight_fdi: in-flight fault detection and post-flight fault isolation for an INS.

Subpackages
-----------
core     pure estimation core (numpy/scipy only, no rclpy): models, Kalman filter,
         backward information filter, chi-square/UDU^T localization, Fisher test, GLR.
sim      simulator and fault catalogue (numpy only).
bagio    rosbag2 reading/writing through rosbags (no rclpy).
nodes    thin rclpy nodes.
cli      the ``flight-fdi`` command.
"""

__version__ = "0.1.0"
