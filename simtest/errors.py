"""Error types. Every error names the bad value, the file or field it came from, and what is allowed."""

from __future__ import annotations


class SimtestError(Exception):
    """Base class of every error simtest raises on purpose."""


class ConfigError(SimtestError, ValueError):
    """A configuration value is missing, of the wrong type or out of its allowed range."""


class AssetError(SimtestError, ValueError):
    """A mesh, model folder or object id is missing, unreadable or invalid."""


class RenderError(SimtestError, RuntimeError):
    """No OpenGL backend could be created, or rendering failed."""


class DatasetError(SimtestError, ValueError):
    """A dataset folder is missing, malformed, or would be overwritten."""


class EstimatorError(SimtestError, RuntimeError):
    """An estimator failed and the run was asked to stop at the first failure (``--fail-fast``); the message
    holds the estimator's traceback."""
