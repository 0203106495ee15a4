"""Appearance as data: materials (albedo, roughness, normal maps, parameters) made by seeded procedural
generators or read from a folder, cached by (family, seed); each renderer maps the same material to what it
can draw. Object appearance read from assets stays in :mod:`simtest.objects.appearance`.
"""
