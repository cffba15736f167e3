"""The package version, here so that no room imports the `urb_jax` façade (urb_jax/__init__.py),
which re-exports from every room."""

__version__ = "0.1.0"
