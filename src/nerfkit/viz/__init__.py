"""Figures, videos and viewers."""
