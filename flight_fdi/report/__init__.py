"""Reports of analysed flights: PNG figures (matplotlib Agg) and an HTML page."""
from .figures import Truth
from .html import write_report

__all__ = ["Truth", "write_report"]
