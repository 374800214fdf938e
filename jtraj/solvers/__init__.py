"""Solvers of knot-structured NLPs."""
