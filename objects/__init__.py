"""Objects: ``ObjectModel`` / ``ObjectSet``, built-in procedural categories, mesh and BOP-model loaders."""

from simtest.objects.model import ContinuousSymmetry, ObjectModel, ObjectSet

__all__ = ["ContinuousSymmetry", "ObjectModel", "ObjectSet"]
