"""The 3-D strapdown INS error-state model (``ins3d``): model, forward filter, observability.

See docs/ins3d.md. Pure numerics (no rclpy); inputs are the decoded contract topics
(``data.NavSteps``, ``data.RefRows``).
"""
