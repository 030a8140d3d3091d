"""Tool paths with a certified scallop height: exact scallop relations, Algorithm 1 rings, chords, gouges, links.

Modules: scallop (exact relations), geometry (fundamental forms), grid (Algorithm 1), rings (contour-parallel
rings and corner pockets), chord (points along passes), gouge (checks against all patches), access (setups),
link (retracts and patch order), plan (the whole stage without files).
"""
