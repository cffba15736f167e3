"""What several test modules share: fakes, digests, tiny run configs and reference models (not tests;
pytest finds this package through `pythonpath = ["tests"]` in pyproject.toml). Fixtures shared by
several modules live in tests/conftest.py."""
