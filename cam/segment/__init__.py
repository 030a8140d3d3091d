"""Segmentation of a quad mesh into sharp height fields (rectangular quad patches bounded by sharp features).

See :mod:`cam.segment.pipeline` for the steps; each step is its own module.
"""

from cam.segment.pipeline import METHODS, Patch, Segmentation, segment_quads

__all__ = ["METHODS", "Patch", "Segmentation", "segment_quads"]
