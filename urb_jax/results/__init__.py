"""Results: day records, metrics, plots, leaderboard and day export."""
