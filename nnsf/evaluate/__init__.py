"""Evaluation: grouped cross-validation of precision vs rank, ISOMAP diagnostics, figures."""
