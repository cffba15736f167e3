"""Shared core: errors, paths, config-file loading, atomic writes, progress."""
