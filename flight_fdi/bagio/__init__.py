"""rosbag2 bag input/output through rosbags (no rclpy).

``read_flight`` (fast reading of one INS channel and its reference), ``read_messages`` (generic
decoded iteration), ``open_writer`` (writing), ``get_typestore`` (Jazzy + flight_fdi_msgs).
"""
from .errors import BagError
from .flight import FlightData, read_flight
from .reader import bag_topics, read_messages
from .typestore import get_typestore, msg_definition
from .writer import BagWriter, open_writer

__all__ = ["BagError", "BagWriter", "FlightData", "bag_topics", "get_typestore", "msg_definition",
           "open_writer", "read_flight", "read_messages"]
