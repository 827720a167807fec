"""Benchmark scripts for the renderer: they print tables and write bench/results/ (not tests)."""
