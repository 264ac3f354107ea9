"""The one place where CDR (the ROS 2 wire format) is encoded and decoded by hand.

Why by hand: per message, rosbags' generic (de)serializer costs ~10-40 us and rclpy's
``serialize_message`` / message construction ~40 us; a 3-hour flight holds ~650 000 velocity
messages and the filter node handles every message on its hot path. Measured on this machine
(docs/design.md, "CDR"): the vectorised series decoders here take well under 1 us per message
and the per-message codecs 1-4 us. So the project keeps one hand-written codec, in three parts:

* :mod:`.series` -- whole series with numpy: TwistStamped / TwistWithCovarianceStamped
  (decode and encode), any header-plus-doubles type (``encode_doubles`` / ``decode_doubles``:
  sensor_msgs/Imu, sensor_msgs/FluidPressure, geometry_msgs/PointStamped),
  NavSatFix (encode; ``decode_doubles`` reads it), :class:`Payloads` (messages stored back to
  back);
* :mod:`.variable` -- the variable-layout messages read or written in series: std_msgs/String,
  flight_fdi_msgs/FilterState (every field as columns, walked with numpy per prefix; or the
  leading fields, or one record per message, from those columns), nav_msgs/Odometry;
* :mod:`.message` -- one message at a time for the nodes: the filter node's inputs and outputs
  (Innovation, FilterState), a message's header stamp / header bytes (player, recorder).

The wire rules (XCDR1 as ROS 2 / Fast DDS put it on the wire):

* a 4-byte encapsulation header: ``00 01 00 00`` (CDR_LE, always written) or ``00 00 00 00``
  (CDR_BE, also read). The last two bytes (options) are not interpreted when reading;
* then the fields in declaration order, each aligned to its own size (int32 / uint32 to 4,
  float64 to 8, bool / uint8 not at all) counted from the first byte *after* the
  encapsulation header; the padding is zero bytes;
* a string is a uint32 length that includes the trailing NUL, the UTF-8 bytes, then the NUL;
* a sequence (``T[]``) is a uint32 element count, then the elements, the first one aligned to
  the element size (nothing is aligned for an empty sequence); a fixed array (``T[N]``) has no
  count; a bool is one byte (0 or 1);
* std_msgs/Header is builtin_interfaces/Time (int32 sec, uint32 nanosec) then string frame_id,
  so every stamped message starts with sec at byte 4, nanosec at 8 and the frame_id length at
  12, and a type made of a header and doubles has its first double at ``4 + align8(12 + L)``.

Every codec is tested against rosbags' serializer (and the per-message ones against rclpy's)
in ``test/bagio/test_bagio_cdr.py`` and ``test/nodes/test_wire.py``.
"""
from .series import (FLUID_PRESSURE, IMU, NAVSATFIX, POINT_STAMPED, TWIST_COV_STAMPED,
                     TWIST_STAMPED, Payloads, decode, decode_doubles, decode_navsatfix_flags,
                     encode, encode_doubles, encode_navsatfix, rows, supported)
from .variable import (FILTER_STATE, FILTER_STATE_SEQUENCES, LINEAR_COV, ODOMETRY, STRING,
                       FilterStateColumns, FilterStateRecord, decode_filter_state_columns,
                       decode_filter_state_x, decode_filter_states, decode_odometry,
                       decode_string, encode_odometry)
from .message import WireError, header_bytes, header_stamp_ns

__all__ = ["FILTER_STATE", "FILTER_STATE_SEQUENCES", "FLUID_PRESSURE", "IMU", "LINEAR_COV",
           "NAVSATFIX", "ODOMETRY", "POINT_STAMPED", "STRING", "TWIST_COV_STAMPED",
           "TWIST_STAMPED", "FilterStateColumns", "FilterStateRecord", "Payloads", "WireError",
           "decode", "decode_doubles", "decode_filter_state_columns", "decode_filter_state_x",
           "decode_filter_states", "decode_navsatfix_flags", "decode_odometry", "decode_string",
           "encode", "encode_doubles", "encode_navsatfix", "encode_odometry", "header_bytes",
           "header_stamp_ns", "rows", "supported"]
