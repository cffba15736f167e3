"""urb-jax: a JAX-native surrogate-plus-SUMO hybrid trainer for the Urban Routing Benchmark."""

__version__ = "0.1.0"
