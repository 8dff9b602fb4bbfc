"""Pipelines that compose methods: performance-driven animation, mesh clean-up, batch jobs."""
