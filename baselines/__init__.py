"""Baseline methods, behind the same interfaces as facegeom's own.

Face driving (``facegeom.deformers`` entry points):

- ``rbf``: RBF interpolation of marker displacements (scipy's RBFInterpolator)
- ``laplacian``: Laplacian surface editing (Sorkine et al. 2004)
- ``arap``: libigl's as-rigid-as-possible deformation
- ``biharmonic``: libigl's biharmonic (k-harmonic) deformation
- ``markers-only``: the reference "markers move, nothing else"

Installed as ``facegeom.baselines`` (the repository keeps the top-level ``baselines/``
folder; ``pyproject.toml`` maps it). facegeom's other modules never import this package;
they find these classes through entry points.
"""
