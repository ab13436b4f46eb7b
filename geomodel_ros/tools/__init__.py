"""Tools around the core: CLI, benchmarks, evaluation, rendering, demo, synthetic scenes, files."""
