"""Errors that tell the user which file, which field, and how to fix it."""

from __future__ import annotations


class UrbJaxError(Exception):
    """Base class: every error we raise on purpose."""


class NetworkError(UrbJaxError):
    """A network folder is missing, incomplete or inconsistent."""

    def __init__(self, file: object, problem: str, fix: str = "") -> None:
        self.file = str(file)
        self.problem = problem
        self.fix = fix
        message = f"{self.file}: {problem}"
        if fix:
            message += f" Fix: {fix}"
        super().__init__(message)


class RouteError(UrbJaxError):
    """Route generation failed for an OD pair."""


class ConfigError(UrbJaxError):
    """A config file has an unknown key, a wrong type or a bad value."""
