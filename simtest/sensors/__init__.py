"""Sensor models that need the scene itself (not only a finished image): an active-stereo depth camera renders
its IR pair through the scene's renderer and hands back the sensed depth, with the exact depth kept beside it.

Image-space depth noise of finished datasets stays in :mod:`simtest.corrupt.depth`.
"""
