"""Adapters for other people's code: PettingZoo AEC/Parallel envs over SUMO days, a JaxMARL env over
a run's surrogate, and SUMO test days for a policy trained outside urb-jax."""
