"""Evaluation: Monte Carlo studies of the detectors and isolation methods (pure, no rclpy)."""
from .errors import EvalError
from .montecarlo import (FlightCase, StudyConfig, StudyResult, by_level, confusion_matrix,
                         declared, error_rates, format_metrics, isolated, plan_study,
                         predicted_class, run_case, run_study, smallest_isolated, summarize)

__all__ = ["EvalError", "FlightCase", "StudyConfig", "StudyResult", "by_level",
           "confusion_matrix", "declared", "error_rates", "format_metrics", "isolated",
           "plan_study", "predicted_class", "run_case", "run_study", "smallest_isolated",
           "summarize"]
