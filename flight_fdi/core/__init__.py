"""Pure estimation core: numpy/scipy only, no rclpy. Usable from a notebook."""
from .errors import CoreError
from .models import LinearModel, attitude_axis, get_model, ins_channel, load_model

__all__ = ["CoreError", "LinearModel", "attitude_axis", "get_model", "ins_channel", "load_model"]
