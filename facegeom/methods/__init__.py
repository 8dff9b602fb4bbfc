"""facegeom's own methods behind the interfaces: the tangent framework (driving and
retargeting) and SEM fitting. Baselines live in the top-level ``baselines`` package."""
