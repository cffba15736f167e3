"""Vectorised JAX MARL algorithms on the functional routing env (IQL, IPPO, MAPPO, QMIX, VDN, IQL*,
IPPO*), each `make_train(config, env) -> train(key)` jitted whole; see docs/algorithms.md."""
