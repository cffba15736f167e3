"""A run's results: records (one row per agent-day), metrics, the leaderboard, day export."""
