"""Candidate physical effects (design.md §4) as model terms. Filled in by the diagnosis work."""
