"""Reports: metrics JSON, metric-vs-step plots, cloud plots (PNG) and interactive 3-D pages (HTML)."""

from tactex.report.cloud import plot_cloud
from tactex.report.html import cloud_html
from tactex.report.metrics import read_metrics, write_metrics
from tactex.report.series import plot_series

__all__ = ["cloud_html", "plot_cloud", "plot_series", "read_metrics", "write_metrics"]
