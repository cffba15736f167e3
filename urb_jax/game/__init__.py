"""The routing game: humans, rewards, observations, mutation and the functional env."""
