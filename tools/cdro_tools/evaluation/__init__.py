"""Evaluation of anchor-free maps against ground truth (cdro-eval); see docs/tools.md."""
