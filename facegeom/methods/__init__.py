"""facegeom's own methods behind the interfaces: the tangent framework (driving and
retargeting) and SEM fitting. Baselines live in ``facegeom.baselines`` (the repository's top-level ``baselines/`` folder)."""
