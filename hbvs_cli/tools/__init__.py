"""Presentation of results: report tables, JSON output, plots and trajectory export."""
