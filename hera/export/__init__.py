"""Records for other tools: :mod:`hera.export.mcap` writes runs (and live clusters) as MCAP
files that Foxglove and Lichtblick open."""
