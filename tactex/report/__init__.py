"""Reports: metrics JSON, metric-vs-step plots, cloud plots (PNG) and interactive 3-D pages (HTML)."""

from tactex.report.cloud import plot_cloud
from tactex.report.compare_plot import plot_compare
from tactex.report.html import cloud_html
from tactex.report.metrics import read_metrics, write_metrics
from tactex.report.run_report import (
    CLEAN_METRIC_KEYS,
    WIPE_METRIC_KEYS,
    RunReport,
    summary_table,
    write_index_html,
    write_run_report,
)
from tactex.report.series import plot_series

__all__ = [
    "CLEAN_METRIC_KEYS",
    "WIPE_METRIC_KEYS",
    "RunReport",
    "cloud_html",
    "plot_cloud",
    "plot_compare",
    "plot_series",
    "read_metrics",
    "summary_table",
    "write_index_html",
    "write_metrics",
    "write_run_report",
]
