"""Reporting: day records, metrics, plots, leaderboard and day export (what results folders hold)."""
