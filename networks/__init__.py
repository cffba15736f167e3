"""Embedded networks shipped with urb-jax (installed as the package urb_jax.networks)."""
