"""Benchmarks (`hypergs bench ...`): each module measures one thing and returns a report dict; common.py
holds what they share. No Blender here: the benchmark that drives Blender headless is tools/bench_splat.py
(`hypergs bench splat` runs it)."""
