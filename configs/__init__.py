"""Shipped JSON configs (installed as the package urb_jax.configs): algo/, env/, task/."""
